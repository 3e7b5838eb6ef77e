"""The ``handeye`` command line: each command's basic path, the error mapping and the start-up imports.

The workflow's numbers are tested in test_pipeline.py; here the commands must pass the flags through,
print what the README promises and map errors to one line and an exit code.
"""

import ast
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from handeye.cli import main
from handeye.conventions import VENDOR_POSE_FORMAT, pose_values_from_T
from handeye.errors import EXIT_CODES, InputError, QAFailed, SessionRefused
from handeye.frames import T_from_rotvec, inv_T, pose_error, rotvec_from_R, transform_points
from handeye.mounting import mounting
from handeye.session import load_session
from handeye.sim.corners import make_corner_session
from handeye.sim.scenarios import default_intrinsics
from handeye.sim.vendor import write_vendor_session

SMALL = dict(intrinsics=default_intrinsics(640, 480), supersample=3)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "session"
    write_vendor_session(out, mode="eye_to_hand", n_views=8, seed=5, image_noise=1.0, **SMALL)
    return out


@pytest.fixture(scope="module")
def calibrated(session, tmp_path_factory):
    """`handeye calibrate` with the closed form only, no report: (out dir, stdout)."""
    out = tmp_path_factory.mktemp("cal") / "out"
    cap = subprocess.run(
        [
            sys.executable,
            "-m",
            "handeye.cli",
            "-q",
            "calibrate",
            str(session),
            "--out",
            str(out),
            "--no-report",
            "--no-refine",
            "--method",
            "park",
        ],
        capture_output=True,
        text=True,
    )
    assert cap.returncode == 0, cap.stderr
    assert cap.stderr == ""  # -q: nothing on stderr for a good run
    return out, cap.stdout


def test_calibrate_prints_the_matrix_it_wrote(calibrated):
    out, stdout = calibrated
    res = json.loads((out / "result.json").read_text())
    assert res["method"] == "park" and res["refined"] is False and res["status"] == "ok"
    lines = stdout.splitlines()
    k = lines.index("T_base_cam (p_base = T_base_cam @ p_cam):")
    printed = np.array([[float(x) for x in line.strip(" []").split()] for line in lines[k + 1 : k + 5]])
    np.testing.assert_allclose(printed, np.asarray(res["T_base_cam"]), atol=5e-7)  # printed with 6 decimals
    assert lines[-1] == f"result: {out / 'result.json'}"
    assert not (out / "report.html").exists()


def test_calibrate_flags_reach_the_options(session, tmp_path):
    out = tmp_path / "out"
    site = tmp_path / "site.yaml"
    site.write_text(yaml.safe_dump({"refine_options": {"robot_sigma_mm": 0.5}}))
    rc = main(
        [
            "-q",
            "calibrate",
            str(session),
            "--out",
            str(out),
            "--no-report",
            "--fix",
            "p1",
            "p2",
            "--robot-noise",
            "fixed",
            "--robot-sigma",
            "0.3",
            "0.04",
            "--config",
            str(site),
            "--workers",
            "1",
        ]
    )
    assert rc == 0
    opts = json.loads((out / "result.json").read_text())["provenance"]["options"]
    # the flag wins over the site file, which wins over the preset
    assert opts["robot_noise"] == "fixed" and opts["robot_sigma_mm"] == 0.3 and opts["robot_sigma_deg"] == 0.04
    assert tuple(opts["fix"]) == ("p1", "p2")


def test_calibrate_failure_is_one_line_with_the_exit_code_of_its_error(session, tmp_path, capsys, session_with_board):
    bad = session_with_board(session, tmp_path / "bad", cols=9, rows=6)
    rc = main(["-q", "calibrate", str(bad), "--out", str(tmp_path / "out"), "--no-report"])
    assert rc == 3  # DetectionError
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "found in only 0 of 8 images" in err[0] and "9x6" in err[0]
    assert json.loads((tmp_path / "out" / "result.json").read_text())["error"]["code"] == "target_not_found"


def test_unknown_config_key_is_named(session, tmp_path, capsys):
    p = tmp_path / "site.yaml"
    p.write_text(yaml.safe_dump({"methd": "park"}))
    assert main(["calibrate", str(session), "--config", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "unknown setting 'methd'" in err


def test_debug_prints_the_traceback_and_keeps_the_exit_code(tmp_path, capsys):
    assert main(["--debug", "-q", "calibrate", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("Traceback (most recent call last):") and "InputError" in err
    assert err.strip().splitlines()[-1].startswith("handeye: error: ") and "missing" in err.splitlines()[-1]
    assert main(["-q", "calibrate", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert "Traceback" not in capsys.readouterr().err


def test_a_closed_pipe_ends_quietly_and_another_broken_pipe_is_named(monkeypatch, capsys):
    """``handeye ... | head``: the reader of stdout goes away mid-print; no error line blaming the file system,
    exit 141. A broken pipe that is not stdout's stays the one-line refusal of the file system."""
    import io
    import os

    import handeye.cli.apply as apply_cli
    from handeye.errors import OUTPUT_CLOSED_EXIT_CODE

    def prints(args):
        for _ in range(10000):
            print("p_base [m]: 0 0 0")
        return 0

    monkeypatch.setattr(apply_cli, "run", prints)
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader went away
    with open(write_end, "w") as closed:
        monkeypatch.setattr("sys.stdout", closed)
        assert main(["apply", "r", "--point", "0", "0", "1"]) == OUTPUT_CLOSED_EXIT_CODE == 141
    assert capsys.readouterr().err == ""

    def other_pipe(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(apply_cli, "run", other_pipe)
    monkeypatch.setattr("sys.stdout", io.StringIO())
    assert main(["apply", "r", "--point", "0", "0", "1"]) == 2
    assert capsys.readouterr().err.startswith("handeye: error: the file system refused (Broken pipe)")


def test_simulate_writes_the_session_it_promises(tmp_path, capsys):
    out = tmp_path / "sim"
    assert (
        main(["-q", "simulate", str(out), "--views", "3", "--seed", "3", "--hidden", "2", "--mode", "eye_in_hand"]) == 0
    )
    assert capsys.readouterr().out.splitlines()[0] == f"synthetic eye_in_hand session with 3 rendered views: {out}"
    s = load_session(out)
    assert [v.view_id for v in s.views] == ["1", "2", "3"] and s.mode == "eye_in_hand"
    truth = json.loads((out / "ground_truth.json").read_text())
    assert truth["mode"] == "eye_in_hand" and np.asarray(truth["T_end_cam"]).shape == (4, 4)
    assert main(["simulate", str(tmp_path / "few"), "--views", "2"]) == 2
    assert "--views must be at least 3" in capsys.readouterr().err


def test_simulate_an_arm_further_from_its_table(tmp_path, capsys):
    """--dh-error MM DEG and --encoder-sigma DEG set the simulated arm's kinematic errors: each DH length and
    angle error between a fifth of the given bound and the bound, recorded in ground_truth.json; without the
    kinematic model they are refused."""
    out = tmp_path / "arm"
    assert (
        main(
            [
                "-q",
                "simulate",
                str(out),
                "--views",
                "4",
                "--seed",
                "2",
                "--robot-error",
                "kinematic",
                "--dh-error",
                "2.5",
                "0.25",
                "--encoder-sigma",
                "0.02",
            ]
        )
        == 0
    )
    err = json.loads((out / "ground_truth.json").read_text())["robot_error"]
    e = np.abs(np.asarray(err["dh_error_mm_deg"], float))
    lengths, angles = e[:, [0, 2]], e[:, [1, 3]]
    assert lengths.min() >= 0.5 - 1e-9 and lengths.max() <= 2.5 + 1e-9 and lengths.max() > 1.0
    assert angles.min() >= 0.05 - 1e-9 and angles.max() <= 0.25 + 1e-9
    assert err["encoder_sigma_deg"] == pytest.approx(0.02)
    capsys.readouterr()
    assert main(["simulate", str(tmp_path / "iid"), "--views", "3", "--dh-error", "1", "0.1"]) == 2
    assert "add --robot-error kinematic" in capsys.readouterr().err
    for flag, values, words in (
        ("--encoder-sigma", ["-1"], "--encoder-sigma must be"),
        ("--encoder-sigma", ["inf"], "--encoder-sigma must be"),
        ("--dh-error", ["inf", "0.1"], "--dh-error must be"),
        ("--dh-error", ["1", "nan"], "--dh-error must be"),
    ):
        assert (
            main(["simulate", str(tmp_path / "bad"), "--views", "3", "--robot-error", "kinematic", flag] + values) == 2
        ), (flag, values)
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "bad").exists()


def test_demo_reports_its_error_against_the_truth(tmp_path, capsys):
    assert main(["-q", "demo", "--out", str(tmp_path / "demo"), "--views", "8", "--mode", "eye_to_hand"]) == 0
    out = capsys.readouterr().out
    line = [ln for ln in out.splitlines() if ln.startswith("error against the ground truth")][0]
    t_mm, r_deg = float(line.split(":")[1].split("mm")[0]), float(line.split(",")[1].split("deg")[0])
    res = json.loads((tmp_path / "demo" / "result" / "result.json").read_text())
    truth = json.loads((tmp_path / "demo" / "session" / "ground_truth.json").read_text())
    r, t = pose_error(np.asarray(res["T_base_cam"]), np.asarray(truth["T_base_cam"]))
    assert abs(t_mm - t) < 1e-3 and abs(r_deg - r) < 1e-4  # the printed error is the real one
    # 8 rendered views with 2 grey levels of noise and blur: refined sigmas ~0.1 mm, 0.03 deg
    assert t_mm < 5 * np.linalg.norm(res["refinement"]["sigma_trans_mm"]) + 0.05
    assert (tmp_path / "demo" / "result" / "report.html").exists()
    assert "T_base_cam" in out
    # run again into the same folder: its own rendered session is rendered again, the same error results
    assert main(["-q", "demo", "--out", str(tmp_path / "demo"), "--views", "8", "--mode", "eye_to_hand"]) == 0
    assert line in capsys.readouterr().out


def test_simulate_refuses_a_session_folder_unless_forced(tmp_path, capsys):
    args = ["simulate", str(tmp_path / "s"), "--views", "3", "--seed", "2"]
    assert main(args) == 0
    first = (tmp_path / "s" / "poses.txt").read_text()
    capsys.readouterr()
    assert main([*args, "--seed", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already holds a session" in err[0] and "--force" in err[0]
    assert (tmp_path / "s" / "poses.txt").read_text() == first  # nothing written over
    assert main([*args, "--seed", "5", "--force"]) == 0
    assert (tmp_path / "s" / "poses.txt").read_text() != first


def _refused_at_parsing(argv: list, capsys) -> str:
    """The error line of a command line argparse refuses (exit 2, its usage and one error line)."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["-q", *map(str, argv)])
    assert e.value.code == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ": error:" in ln]
    assert len(err) == 1, err
    return err[0]


SIM_COLLECT = ["--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim"]


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "OUT", "--views", "3"],
        ["demo", "--out", "OUT", "--views", "4"],
        ["collect", "OUT", *SIM_COLLECT, "--auto"],
    ],
    ids=["simulate", "demo", "collect"],
)
def test_a_negative_seed_is_refused_before_anything_is_written(argv, tmp_path, capsys):
    """numpy takes seeds >= 0: --seed -1 is a usage error naming --seed, not an internal error after the work began."""
    out = tmp_path / "out"
    argv = [str(out) if a == "OUT" else a for a in argv]
    for seed in ("-1", "1.5"):
        err = _refused_at_parsing([*argv, "--seed", seed], capsys)
        assert "argument --seed: expected a whole number >= 0" in err and repr(seed) in err, err
    assert not out.exists()


@pytest.mark.parametrize(
    "argv, option",
    [
        (["simulate", "OUT", "--robot-noise", "nan", "0"], "--robot-noise"),
        (["simulate", "OUT", "--robot-noise", "0.1", "inf"], "--robot-noise"),
        (["simulate", "OUT", "--robot-noise", "-1", "0"], "--robot-noise"),
        (["simulate", "OUT", "--noise-px", "nan"], "--noise-px"),
        (["simulate", "OUT", "--noise-px", "-2"], "--noise-px"),
        (["simulate", "OUT", "--blur", "nan"], "--blur"),
        (["simulate", "OUT", "--blur", "1e7"], "--blur"),  # OpenCV's kernel would exhaust the memory
        (["simulate", "OUT", "--gamma", "0"], "--gamma"),
        (["simulate", "OUT", "--gamma", "nan"], "--gamma"),
        (["demo", "--out", "OUT", "--views", "3"], "--views"),  # one hidden: calibrate would find 2 boards
        (["collect", "OUT", *SIM_COLLECT, "--sim-pose-noise", "nan", "0"], "--sim-pose-noise"),
        (["collect", "OUT", *SIM_COLLECT, "--sim-pose-noise", "0.1", "-1"], "--sim-pose-noise"),
        (["collect", "OUT", *SIM_COLLECT, "--sim-image-noise", "-5"], "--sim-image-noise"),
        (["collect", "OUT", *SIM_COLLECT, "--sim-image-noise", "inf"], "--sim-image-noise"),
        (["collect", "OUT", *SIM_COLLECT, "--sim-blur", "-1"], "--sim-blur"),
        (["collect", "OUT", *SIM_COLLECT, "--sim-blur", "nan"], "--sim-blur"),
        (["collect", "OUT", *SIM_COLLECT, "--sim-supersample", "0"], "--sim-supersample"),
        (["collect", "OUT", *SIM_COLLECT, "--sim-bump", "nan", "0"], "--sim-bump"),
    ],
)
def test_simulator_numbers_that_mean_nothing_are_refused_naming_the_option(argv, option, tmp_path, capsys):
    """nan, inf and negative noise levels, blurs and samples: before, simulate wrote poses of nan and rendered
    nan noise as none, and collect failed at its first render with a message naming no option."""
    out = tmp_path / "out"
    err = _refused_at_parsing([str(out) if a == "OUT" else a for a in argv], capsys)
    assert f"argument {option}: expected" in err, err
    assert not out.exists()


@pytest.mark.parametrize(
    "ids, words",
    [
        (["--hidden", "1", "2", "3"], "--hidden hides every view: none of the 3 would show the board"),
        (["--hidden", "3", "1", "2", "--outliers"], "--hidden hides every view"),
        (["--hidden", "4"], "--hidden names views that do not exist"),
        (["--hidden", "2", "2"], "--hidden names a view twice"),
        (["--outliers", "0"], "--outliers names views that do not exist"),
        (["--hidden", "1", "--outliers", "1"], "both in --hidden and in --outliers"),
    ],
)
def test_simulate_names_the_option_of_view_ids_it_cannot_use(ids, words, tmp_path, capsys):
    """Every view hidden said "too few views; expected n_views >= 1; got 0", naming no option."""
    out = tmp_path / "sim"
    assert main(["-q", "simulate", str(out), "--views", "3", *ids]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert not out.exists()


@pytest.mark.parametrize(
    "argv, words",
    [
        (["simulate", "OUT", "--views", "3"], "OUT is a file, not a folder"),
        (["simulate", "OUT/s", "--views", "3"], "OUT lies under a file"),
        (["simulate", "OUT", "--cell", "2", "--views", "4"], "OUT is a file, not a folder"),
        (["collect", "OUT", *SIM_COLLECT, "--auto", "--seed", "1"], "OUT is a file, not a folder"),
        (["demo", "--out", "OUT", "--views", "4"], "--out is a file, not a folder"),
    ],
)
def test_an_output_folder_that_is_a_file_is_called_one(argv, words, tmp_path, capsys):
    """Before, simulate said "cannot read OUT (File exists)" and collect "output folder is not empty"."""
    f = tmp_path / "afile"
    f.write_text("mine")
    assert main(["-q", *(a.replace("OUT", str(f)) if a.startswith("OUT") else a for a in argv)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{f}" in err[0] and words in err[0], err
    assert f.read_text() == "mine"


def test_simulate_refused_after_its_checks_leaves_no_folder(tmp_path, capsys):
    """An arm that does not exist is found out while the session is drawn: the folders made for OUT go again."""
    out = tmp_path / "new" / "sim"
    assert main(["-q", "simulate", str(out), "--views", "3", "--robot-error", "kinematic", "--arm", "nosuch"]) == 2
    assert "nosuch" in capsys.readouterr().err
    assert not (tmp_path / "new").exists()


def test_apply_maps_a_camera_point_into_the_base(tmp_path, capsys):
    cs = make_corner_session(mode="eye_in_hand", n_views=3, seed=2, noise_px=0.0)
    (tmp_path / "result.json").write_text(
        json.dumps({"status": "ok", "mode": cs.mode, cs.x_name: cs.T_x_true.tolist()})
    )
    p_board = cs.target.object_points()[7]
    p_cam = transform_points(cs.T_cam_board_true[1], p_board)
    end = pose_values_from_T(cs.T_base_end_true[1], VENDOR_POSE_FORMAT)
    assert (
        main(
            [
                "apply",
                str(tmp_path),
                "--point",
                *(f"{x * 1e3:.9f}" for x in p_cam),
                "--mm",
                "--end-pose",
                *(f"{v * (1e3 if k < 3 else 1):.9f}" for k, v in enumerate(end)),
            ]
        )
        == 0
    )
    got = [float(x) for x in capsys.readouterr().out.splitlines()[0].split(":")[1].split()]
    np.testing.assert_allclose(got, transform_points(cs.T_board_true, p_board), atol=2e-6)  # board fixed in base
    assert main(["apply", str(tmp_path), "--point", "0", "0", "1"]) == 2  # eye-in-hand needs --end-pose
    assert "--end-pose" in capsys.readouterr().err


def test_import_visp_writes_a_session_with_the_same_poses(tmp_path, capsys):
    cs = make_corner_session(mode="eye_in_hand", n_views=3, seed=1, noise_px=0.0)
    src = tmp_path / "visp"
    src.mkdir()
    (src / "chessboard-data.txt").write_text("9 x 6\nsquare size: 0.0236 m\n")
    for k, T in enumerate(cs.T_base_end_true, start=1):
        (src / f"img_image-{k}.png").write_bytes(b"")  # the importer only points at the images
        data = [[float(v)] for v in (*T[:3, 3], *rotvec_from_R(T[:3, :3]))]
        (src / f"img_pose_rPe_{k}.yaml").write_text(yaml.safe_dump({"rows": 6, "cols": 1, "data": data}))
    assert main(["import", "visp", str(src), str(tmp_path / "out")]) == 0
    assert capsys.readouterr().out.strip().splitlines() == [
        "ViSP layout: chessboard 9x6 inner corners, 23.6 mm; mode: from the data (ViSP's chessboard layout serves "
        "both mounting modes)",
        f"session: {tmp_path / 'out' / 'session.yaml'}",
    ]
    s = load_session(tmp_path / "out")
    assert s.target.cols == 9 and s.target.rows == 6 and abs(s.target.square_m - 0.0236) < 1e-12
    for v, T in zip(s.views, cs.T_base_end_true, strict=False):
        np.testing.assert_allclose(v.T_base_end, T, atol=1e-12)


def test_report_rebuilds_the_markdown_from_the_result_folder(calibrated, tmp_path, capsys):
    out, _ = calibrated
    dest = tmp_path / "rep"
    assert main(["-q", "report", str(out), "--out", str(dest), "--format", "md"]) == 0
    assert capsys.readouterr().out.strip() == f"report: {dest / 'report.md'}"
    md = (dest / "report.md").read_text()
    res = json.loads((out / "result.json").read_text())
    assert f"{res['hand_eye']['translation_mm'][0]:+.2f}"[1:] in md  # the result's numbers, not a template
    assert not (dest / "report.html").exists()
    assert main(["report", str(tmp_path / "empty")]) == 2


def test_collect_with_simulators_writes_a_session_that_loads(tmp_path, capsys):
    out = tmp_path / "col"
    assert (
        main(
            [
                "-q",
                "collect",
                str(out),
                "--mode",
                "eye_to_hand",
                "--camera",
                "sim",
                "--robot",
                "sim",
                "--auto",
                "--views",
                "3",
                "--seed",
                "4",
                "--sim-supersample",
                "1",
            ]
        )
        == 0
    )
    first = capsys.readouterr().out.splitlines()[0]
    n_kept = int(first.split("(")[1].split()[0])
    s = load_session(out)
    assert len(s.views) == n_kept >= 6  # start + 3 probes + 3 planned, minus rejected captures
    assert main(["collect", str(out), "--mode", "eye_to_hand", "--camera", "sim", "--robot", "sim"]) == 2
    assert "not empty" in capsys.readouterr().err


def _loaded_by(argv: list) -> list:
    """Command modules and libraries (numpy and heavier) imported by ``handeye ARGV`` in a new process.

    ``handeye.cli.numbers`` (the argument types, standard library only) is no command's module.
    """
    code = (
        "import sys; from handeye.cli import main\ntry: main(sys.argv[1:])\nexcept SystemExit: pass\n"
        "print(sorted(m for m in sys.modules if m.startswith('handeye.cli.') and m != 'handeye.cli.numbers' "
        "or m in ('numpy', 'scipy', 'matplotlib', 'gtsam', 'jinja2', 'cv2')))"
    )
    p = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, check=True)
    return ast.literal_eval(p.stdout.strip().splitlines()[-1])


def test_help_loads_only_the_chosen_command():
    """``handeye --help`` lists every command without importing one; ``handeye CMD --help`` imports
    that command's module alone, and the report's help no numerical library."""
    assert _loaded_by(["--help"]) == []
    assert _loaded_by(["report", "--help"]) == ["handeye.cli.report"]
    assert _loaded_by(["import", "--help"]) == ["handeye.cli.import_"]
    env = dict(os.environ, COLUMNS="200")  # one line per command
    top = subprocess.run(
        [sys.executable, "-m", "handeye.cli", "--help"], capture_output=True, text=True, check=True, env=env
    ).stdout.splitlines()
    k = top.index("  COMMAND")
    listed = [line.split()[0] for line in top[k + 1 : top.index("", k)]]
    from handeye.cli import COMMANDS

    assert listed[:7] == ["calibrate", "simulate", "demo", "apply", "import", "report", "collect"]
    assert listed == list(COMMANDS)  # and every command added after them
    assert "    report       (re)build report.html and report.md from a result folder" in top
    for command in listed:
        cap = subprocess.run([sys.executable, "-m", "handeye.cli", command, "--help"], capture_output=True, text=True)
        assert cap.returncode == 0 and cap.stdout.startswith(f"usage: handeye {command}"), (command, cap.stderr)
        assert re.search(r"^  +--(?!help)", cap.stdout, re.M), command  # the module's own options are there


def test_python_dash_m_handeye_is_the_command_with_its_exit_codes(tmp_path):
    """``python -m handeye`` (a scripts folder off the PATH) runs the command and returns its exit code."""
    cap = subprocess.run(
        [sys.executable, "-m", "handeye", "calibrate", str(tmp_path / "none")], capture_output=True, text=True
    )
    assert cap.returncode == InputError.exit_code == 2, cap.stderr
    assert cap.stderr.startswith("handeye: error: ") and "session not found" in cap.stderr


def test_version_is_read_only_when_asked(capsys):
    """``handeye --version`` prints the installed version; ``--help`` and ``import handeye`` do not read it."""
    import importlib.metadata

    from handeye import __version__

    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out == f"handeye {__version__}\n"
    assert __version__ == importlib.metadata.version("handeye")
    help_run = "import sys; from handeye.cli import main\ntry: main(['--help'])\nexcept SystemExit: pass"
    assert "importlib.metadata" not in _modules_after(help_run)
    assert "importlib.metadata" not in _modules_after("import handeye")


def _modules_after(code: str, *argv: str) -> set:
    """The modules a new process has imported after running ``code`` (``argv`` as its ``sys.argv[1:]``)."""
    code += "\nimport sys; print(sorted(sys.modules))"
    p = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, check=True)
    return set(ast.literal_eval(p.stdout.strip().splitlines()[-1]))


def test_calibrate_imports_what_an_image_session_uses(session, tmp_path):
    """The command's imports stop at what runs before the work; an image session imports no pose-only code.

    Importing the calibrate command and the workflow imports neither the statistics, GTSAM nor the
    diagnostics: each comes with the stage that uses it. The whole ``calibrate --no-report`` on an image
    session imports the tracker sessions' pipeline and refinement, the report's figures and templates, the
    export writers and scipy not at all (the statistics' tails are handeye.special's).
    """
    heavy = {"handeye.special", "gtsam", "handeye.stats", "handeye.diagnose", "handeye.refine.refinement"}
    before = _modules_after("import handeye.cli.calibrate, handeye.workflow")
    assert not heavy & before
    run = "import sys; from handeye.cli import main\ntry: main(sys.argv[1:])\nexcept SystemExit: pass"
    after = _modules_after(run, "-q", "calibrate", str(session), "--out", str(tmp_path / "o"), "--no-report")
    assert (tmp_path / "o" / "result.json").is_file()
    assert heavy <= after  # they did run
    unused = {
        "handeye.pipeline.poseonly",
        "handeye.refine.poseonly",
        "handeye.refine.poseonly_robot",
        "handeye.report.render",
        "handeye.report.plots",
        "handeye.export.writers",
        "matplotlib",
        "jinja2",
        "scipy",
    }
    assert not unused & after


def test_calibrate_freezes_the_imports_once(session, tmp_path):
    """The objects alive after calibrate's imports leave the collector's passes, once per process."""
    code = (
        "import gc, sys\nfrom handeye.cli import freeze_imports, main\n"
        "assert gc.get_freeze_count() == 0\n"
        "main(['-q', 'calibrate', sys.argv[1], '--out', sys.argv[2], '--no-report'])\n"
        "n = gc.get_freeze_count()\nfreeze_imports()\nprint(n, gc.get_freeze_count())"
    )
    p = subprocess.run(
        [sys.executable, "-c", code, str(session), str(tmp_path / "o")], capture_output=True, text=True, check=True
    )
    first, again = map(int, p.stdout.split()[-2:])
    assert first > 10_000  # numpy's, pydantic's and handeye's modules at least
    assert again == first  # a second call freezes nothing (it would keep the first run's garbage)
    assert json.loads((tmp_path / "o" / "result.json").read_text())["status"] == "ok"


def test_site_min_corners_overrides_the_detection_preset(session, tmp_path, capsys):
    site = tmp_path / "site.yaml"
    site.write_text(yaml.safe_dump({"min_corners": 89}))  # the 11x8 board has 88 corners
    assert (
        main(["-q", "calibrate", str(session), "--config", str(site), "--out", str(tmp_path / "o"), "--no-report"]) == 3
    )
    assert "found in only 0 of 8 images" in capsys.readouterr().err


# ------------------------------------------------------------------------------ verdict and exit codes
@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    """10 rendered eye-in-hand views that pass every QA check, in a vendor folder whose config.yaml states
    no mode (vendor folders without one must just work: the data decide it)."""
    out = tmp_path_factory.mktemp("clean") / "session"
    write_vendor_session(out, mode="eye_in_hand", n_views=10, seed=5, image_noise=1.0, **SMALL)
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    del cfg["mode"]
    (out / "config.yaml").write_text(yaml.safe_dump(cfg))
    return out


def _variant(clean, dst, T_base_end) -> Path:
    """The clean session with its mode stated and poses.txt rewritten with ``T_base_end`` (line k = image k)."""
    shutil.copytree(clean, dst)
    cfg = yaml.safe_load((dst / "config.yaml").read_text())
    (dst / "config.yaml").write_text(yaml.safe_dump(dict(cfg, mode="eye_in_hand")))
    lines = [",".join(f"{v:.9f}" for v in pose_values_from_T(T, VENDOR_POSE_FORMAT)) for T in T_base_end]
    (dst / "poses.txt").write_text("\n".join(lines) + "\n")
    return dst


def _reported(session) -> np.ndarray:
    return np.stack([v.T_base_end for v in load_session(session).views])  # (N, 4, 4), image order


def _calibrate(session, out, capsys, *extra):
    """`handeye -q calibrate` in this process: (exit code, stdout lines, stderr lines, result.json)."""
    rc = main(["-q", "calibrate", str(session), "--out", str(out), *extra])
    cap = capsys.readouterr()
    res = json.loads((out / "result.json").read_text()) if (out / "result.json").exists() else None
    return rc, cap.out.splitlines(), cap.err.splitlines(), res


def test_robot_names_the_arm_whose_kinematic_error_the_refinement_models(clean, tmp_path, capsys):
    """A vendor folder (no joint angles) of a simulated RM65 with DH errors: --robot rm65 gets the joint angles by
    inverse kinematics and models the robot error in them; an unknown arm is one error line before any work."""
    kin = write_vendor_session(
        tmp_path / "kin", mode="eye_in_hand", n_views=8, seed=4, robot_error="kinematic", arm="rm65", **SMALL
    )
    assert not (kin / "session.yaml").exists()  # the vendor layout alone: no joint angles, no robot named
    rc, out, err, res = _calibrate(kin, tmp_path / "o", capsys, "--no-report", "--robot", "rm65")
    assert res["status"] == "ok" and rc in (0, QAFailed.exit_code)
    model = res["refinement"]["robot_model"]
    assert model["kind"] == "kinematic" and "RM65" in model["arm"]
    rc, out, err, res = _calibrate(clean, tmp_path / "bad", capsys, "--robot", "no-such-arm")
    assert rc == 2 and res is None and len(err) == 1 and "no-such-arm" in err[0]


def _verdict_block(lines):
    """The verdict line and the lines of its checks and findings."""
    k = next(i for i, line in enumerate(lines) if line.startswith("verdict: "))
    items = []
    for line in lines[k + 1 :]:
        if not line.startswith(("  FAIL ", "  WARN ")):
            break
        items.append(line)
    return lines[k], items


def test_a_clean_session_passes_exits_0_and_says_which_mode_the_data_chose(clean, tmp_path, capsys):
    rc, out, err, res = _calibrate(clean, tmp_path / "o", capsys, "--no-report")
    assert rc == 0 and err == []
    assert res["status"] == "ok" and res["verdict"] == "PASS"
    assert all(f["severity"] == "info" for f in res["findings"]), res["findings"]
    assert res["mode"] == "eye_in_hand" and res["mode_source"] == "detected"
    mode_line = [line for line in out if line.startswith("mode: ")]
    assert mode_line == [
        f"mode: eye_in_hand, detected from the data (the session states none): {res['mode_evidence']['summary']}"
    ]
    verdict, items = _verdict_block(out)
    assert verdict == f"verdict: PASS - {res['verdict_headline']}" and items == []
    assert out.index(verdict) > out.index("T_end_cam (p_end = T_end_cam @ p_cam):")  # after the result block
    assert all(c["status"] == "pass" for c in res["qa"]["checks"])


@pytest.mark.parametrize("level", ["warn", "fail"])
def test_a_site_qa_file_makes_the_same_run_warn_or_fail(clean, tmp_path, capsys, level):
    site = tmp_path / "qa.yaml"  # the rendered corners fit to ~0.05 px: a 0.01 px limit is crossed
    site.write_text(yaml.safe_dump({"checks": {"reprojection_rms_px": {f"{level}_above": 0.01}}}))
    extra = ["--qa", str(site)] + (["--no-report"] if level == "warn" else [])
    rc, out, err, res = _calibrate(clean, tmp_path / "o", capsys, *extra)
    assert res["status"] == "ok" and "T_end_cam" in res  # a matrix either way: status says only that
    assert res["verdict"] == level.upper()
    check = next(c for c in res["qa"]["checks"] if c["key"] == "reprojection_rms_px")
    assert check["status"] == level and check["limits"]["reprojection_rms_px"][f"{level}_above"] == 0.01
    verdict, items = _verdict_block(out)
    assert verdict.startswith(f"verdict: {level.upper()} - ")
    assert items == [
        f"  {level.upper()} {check['short']} -> fix: {check['action'][:1].lower()}{check['action'][1:].rstrip('.')}"
    ]
    if level == "warn":
        assert rc == 0 and err == []
    else:  # FAIL: its own exit code, and the result and the reports are still written
        assert rc == QAFailed.exit_code == 7
        assert err == [f"handeye: verdict FAIL: {res['verdict_headline']}"]
        assert (tmp_path / "o" / "report.html").exists() and (tmp_path / "o" / "report.md").exists()
        assert out[-2:] == [f"report: {tmp_path / 'o' / 'report.html'}", f"report: {tmp_path / 'o' / 'report.md'}"]


def test_a_board_that_slipped_fails_with_the_finding_and_its_fix(clean, tmp_path, capsys):
    mount = mounting("eye_in_hand")
    T = _reported(clean)
    B = np.asarray(json.loads((clean / "ground_truth.json").read_text())[mount.board_name])
    move = T_from_rotvec(np.radians([0.0, 0.0, 1.0]), [0.008, 0.004, 0.0])  # 9 mm and 1 deg from view 7 on
    for k in range(6, len(T)):
        T[k] = mount.T_base_end_from_M(mount.M_from_T_base_end(T[k]) @ B @ move @ inv_T(B))
    rc, out, err, res = _calibrate(_variant(clean, tmp_path / "moved", T), tmp_path / "o", capsys, "--no-report")
    assert rc == QAFailed.exit_code and res["status"] == "ok" and res["verdict"] == "FAIL"
    f = next(f for f in res["findings"] if f["code"] == "board_moved")
    verdict, items = _verdict_block(out)
    assert verdict.startswith("verdict: FAIL - ") and "board" in verdict
    assert items[0] == f"  FAIL board_moved: {f['title'].rstrip('.')} -> fix: {f['action'].rstrip('.')}"
    assert all(" -> fix: " in line for line in items)
    assert len(err) == 1 and err[0].startswith("handeye: verdict FAIL: ")


def test_shuffled_pairs_are_refused_without_a_matrix(clean, tmp_path, capsys, monkeypatch):
    """... and the pairing is searched once: the pipeline's gate searches, the diagnostics decide on its search."""
    from handeye.diagnose.pairing import PairingSearch

    searched = {"shift": 0, "shuffle": 0}
    for part in searched:
        real = getattr(PairingSearch, f"_search_{part}")

        def counted(self, _real=real, _part=part):
            searched[_part] += 1
            return _real(self)

        monkeypatch.setattr(PairingSearch, f"_search_{part}", counted)
    T = _reported(clean)[np.random.default_rng(3).permutation(10)]
    rc, out, err, res = _calibrate(_variant(clean, tmp_path / "shuffled", T), tmp_path / "o", capsys, "--no-report")
    assert searched == {"shift": 1, "shuffle": 1}
    assert res["diagnostics"]["stages"]["pairing"] == "ok"
    assert rc == SessionRefused.exit_code == 8
    assert res["status"] == "failed" and res["verdict"] == "REFUSED" and res["error"]["code"] == "pairs_shuffled"
    assert "T_end_cam" not in res and "hand_eye" not in res
    verdict, items = _verdict_block(out)
    assert verdict.startswith("verdict: REFUSED - ") and verdict.endswith(f"-> fix: {res['error']['fix']}")
    assert any(line.startswith("  FAIL pairs_") for line in items)
    assert not any(line.startswith("  [") for line in out)  # no matrix printed
    assert len(err) == 1 and err[0].startswith("handeye: refused: ")


def test_inverted_poses_are_refused_in_one_line_without_a_way_around(clean, tmp_path, capsys, caplog):
    """Poses written as T_end_base with the mode stated: the refinement finds no view whose pose fits, the
    diagnostics name the inversion; the refusal is one line (not 'refused: the session was refused') and no
    line offers --no-refine, a way around it."""
    import logging

    caplog.set_level(logging.INFO)
    T = inv_T(_reported(clean))
    rc, out, err, res = _calibrate(_variant(clean, tmp_path / "inverted", T), tmp_path / "o", capsys, "--no-report")
    assert rc == SessionRefused.exit_code and res["error"]["code"] == "poses_inverted"
    assert err == [f"handeye: {res['failure_reason']}"]
    assert err[0].startswith("handeye: the session was refused: Robot poses are inverted"), err
    said = [r.getMessage() for r in caplog.records] + out + err
    assert not [line for line in said if "--no-refine" in line], said


def test_a_refinement_that_keeps_no_robot_pose_points_at_the_poses_not_at_no_refine():
    from types import SimpleNamespace

    from handeye.pipeline.stages import refinement_error

    reason = "only 0 views left whose robot pose agrees with the camera; need 3"
    e = refinement_error(SimpleNamespace(failure_code="too_few_robot_poses", failure_reason=reason))
    assert e.code == "refinement_failed" and e.what == f"refinement failed: {reason}"
    assert e.hint == (
        "check how the robot poses were written (frame, units, rotation convention) and that each pairs with its image"
    )
    e = refinement_error(SimpleNamespace(failure_code="solver", failure_reason="GTSAM: indeterminant system"))
    assert e.hint == "rerun with --no-refine to get the closed-form result"


def test_a_malformed_poses_file_is_unusable_input(clean, tmp_path, capsys):
    bad = _variant(clean, tmp_path / "bad", _reported(clean))
    lines = (bad / "poses.txt").read_text().splitlines()
    lines[2] = "0.1,0.2,abc,0,0,0"
    (bad / "poses.txt").write_text("\n".join(lines) + "\n")
    rc, out, err, res = _calibrate(bad, tmp_path / "o", capsys, "--no-report")
    assert rc == InputError.exit_code == 2
    assert len(err) == 1 and err[0].startswith("handeye: error: ") and "poses.txt:3" in err[0]
    assert res["status"] == "failed" and res["verdict"] == "FAIL" and res["error"]["exit_code"] == 2


def test_the_exit_codes_of_the_readme_are_those_of_the_code_and_of_help():
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    rows = re.findall(r"^\| (\d+) \| (.+) \|$", readme, flags=re.M)
    assert [(int(c), m) for c, m in rows] == list(EXIT_CODES)
    assert len({c for c, _ in EXIT_CODES}) == len(EXIT_CODES)  # every code means one thing
    for argv in (["--help"], ["calibrate", "--help"]):
        cap = subprocess.run([sys.executable, "-m", "handeye.cli", *argv], capture_output=True, text=True)
        assert cap.returncode == 0
        for code, meaning in EXIT_CODES:
            assert re.search(rf"^\s+{code}\s+{re.escape(meaning)}$", cap.stdout, flags=re.M), (argv, code)


def test_the_mode_line_says_when_the_data_chose_or_could_not_choose():
    from handeye.cli.verdict import mode_lines, verdict_lines

    ev = {"summary": "eye_to_hand fits 40.0 x better"}
    assert mode_lines({"mode": "eye_to_hand", "mode_source": "detected", "mode_evidence": ev}) == [
        "mode: eye_to_hand, detected from the data (the session states none): eye_to_hand fits 40.0 x better"
    ]
    (line,) = mode_lines({"mode": "eye_in_hand", "mode_source": "default", "mode_evidence": {"summary": "undecided"}})
    assert line.startswith("mode: eye_in_hand, the default") and "--mode" in line
    assert mode_lines({"mode": "eye_in_hand", "mode_source": "stated"}) == []
    assert mode_lines({"mode": "eye_in_hand", "mode_source": "flag"}) == []
    assert verdict_lines({"status": "ok"}) == []  # a result.json from before verdicts: nothing invented


def test_a_run_stopped_by_a_file_names_it_and_claims_nothing_of_the_data():
    """A corrupt image: the verdict line said "no result: image cannot be decoded" without the file, and the mode
    line "the data do not decide it" of data never looked at."""
    from handeye.cli.verdict import mode_lines, verdict_lines

    err = {"what": "image cannot be decoded (corrupt or not an image)", "file": "/s/5.jpg", "fix": "re-capture it"}
    res = {"status": "failed", "verdict": "FAIL", "verdict_headline": "x", "error": err, "mode": "eye_in_hand"}
    assert verdict_lines(res)[0] == (
        "verdict: FAIL - no result: /s/5.jpg: image cannot be decoded (corrupt or not an image) -> fix: re-capture it"
    )
    assert mode_lines({**res, "mode_source": "default"}) == [
        "mode: eye_in_hand, the default (the session states none); state it with --mode if this is wrong"
    ]
    line = verdict_lines({**res, "error": {**err, "file": "/s/poses.txt", "line": 6}})[0]
    assert line.startswith("verdict: FAIL - no result: /s/poses.txt:6: image cannot"), line


def test_the_printed_sigmas_say_which_covariance_they_come_from():
    from handeye.cli.calibrate import _sigma_source_words

    ok = {"validation": {"status": "ok"}}
    assert _sigma_source_words("model", ok) == "from the model covariance; the held-out folds agree with it"
    assert _sigma_source_words("model", {"validation": {"status": "not_run"}}).endswith("not validated")
    assert "held-out folds" in _sigma_source_words("validated", ok)
    assert "in each direction" in _sigma_source_words("model+validated", ok)


def test_calibrate_help_groups_every_flag_and_the_module_names_every_command():
    import handeye.cli as cli

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, cli._LazyCommands))
    calibrate = cli.add_command_arguments(sub._name_parser_map["calibrate"], "calibrate")
    groups = {
        g.title: {a.option_strings[0] if a.option_strings else a.dest for a in g._group_actions}
        for g in calibrate._action_groups
    }
    assert groups["input"] == {"session", "--mode", "--config", "--workers", "--shift-poses", "--allow-outside"}
    assert groups["model"] == {
        "--method",
        "--no-refine",
        "--fix-k3",
        "--fix",
        "--robot-noise",
        "--robot-sigma",
        "--robot",
        "--prior",
        "--board-unmoved",
        "--estimate-scale",
        "--robot-accuracy",
    }
    assert groups["output"] == {"--out", "--export"}
    assert groups["reporting"] == {"--qa", "--no-report"}
    grouped = set().union(*(groups[t] for t in ("input", "model", "output", "reporting")))
    every = {a.option_strings[0] if a.option_strings else a.dest for a in calibrate._actions} - {"-h"}
    assert grouped == every  # no flag left outside the four groups
    text = calibrate.format_help()
    assert text.index("\ninput:") < text.index("\nmodel:") < text.index("\noutput:") < text.index("\nreporting:")
    assert len(cli.COMMANDS) == 11
    for name in cli.COMMANDS:  # the module docstring's command table names every command
        assert re.search(rf"\b{name}\b", cli.__doc__), name


def test_calibrate_help_says_the_data_decide_an_unstated_mode():
    import handeye.cli as cli

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, cli._LazyCommands))
    calibrate = cli.add_command_arguments(sub._name_parser_map["calibrate"], "calibrate")
    mode = next(a for a in calibrate._actions if "--mode" in a.option_strings)
    assert mode.help == (
        "mounting mode (overrides the session's own; default: mode: in config.yaml or session.yaml, else detected "
        "from the data, eye_in_hand only when the data do not decide it)"
    )


@pytest.mark.parametrize(
    "flags, handeye_debug, library_debug",
    [((), False, False), (("verbose",), True, False), (("debug",), True, True), (("quiet", "verbose"), False, False)],
)
def test_verbose_is_handeye_s_detail_and_library_debug_lines_only_with_debug(flags, handeye_debug, library_debug):
    """``-v`` shows handeye's debug lines, never the libraries' (PIL's PNG chunks, matplotlib's font search)."""
    import logging

    from handeye.cli import configure_logging

    root = logging.getLogger()
    saved = root.handlers[:], root.level, {n: logging.getLogger(n).level for n in ("handeye", "PIL", "matplotlib")}
    root.handlers = []
    try:
        configure_logging(verbose=True)  # a run before in this process (its levels must not stay)
        root.handlers = []
        configure_logging(**{f: True for f in flags})
        assert logging.getLogger("handeye.refine").isEnabledFor(logging.DEBUG) == handeye_debug
        for library in ("PIL.PngImagePlugin", "matplotlib.font_manager"):
            assert logging.getLogger(library).isEnabledFor(logging.DEBUG) == library_debug
        assert logging.getLogger("handeye.refine").isEnabledFor(logging.INFO) == ("quiet" not in flags)
    finally:
        root.handlers, root.level = saved[0], saved[1]
        for n, level in saved[2].items():
            logging.getLogger(n).setLevel(level)
