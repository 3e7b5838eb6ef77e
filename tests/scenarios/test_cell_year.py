"""A cell's year, command after command, as an integrator chains them.

collect (simulated camera and arm) -> calibrate -> export to every format (each file loaded by a real
parser) -> verify a month later (still valid) -> a bumped camera (drifted) -> ``--prior`` with a few
views -> compare -> batch over the cell's history and over a fleet that mixes modes, boards, a failed
session, verify sessions and a pose-only session. Every JSON file the scenario writes is validated
against the published schemas in docs/.
"""

from __future__ import annotations

import ast
import json
import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from handeye.cli import main
from handeye.errors import DRIFTED_EXIT_CODE, QAFailed
from handeye.frames import pose_error

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[2]
SCHEMAS = {
    "result.json": "result.schema.json",
    "verify.json": "verify.schema.json",
    "batch.json": "batch.schema.json",
    "observations.json": "observations.schema.json",
}
SEED = 3


def _cli(*argv) -> int:
    return main(["-q", *map(str, argv)])


def _cli_reproducible(*argv) -> int:
    """The command in a fresh interpreter, as an integrator runs it.

    The verification plan picks its poses greedily among candidates that score alike to the last bits of
    the installed result; those bits repeat exactly from run to run (calibrateCamera runs on one thread:
    tests/initial/test_intrinsics.py), whatever the interpreter's string hashing, so a seeded simulation
    repeats exactly. The hashing is pinned all the same, so that a regression shows as a changed figure.
    """
    env = dict(os.environ, PYTHONHASHSEED="0")
    return subprocess.run([sys.executable, "-m", "handeye.cli", "-q", *map(str, argv)], env=env).returncode


def _collect(out: Path, *extra) -> int:
    args = ("collect", out, "--mode", "eye_in_hand", "--camera", "sim", "--robot", "sim", "--auto", "--yes", *extra)
    return _cli_reproducible(*args)


def _validate_tree(root: Path) -> int:
    """Validate every result.json / verify.json / batch.json / observations.json under ``root``; the count."""
    import jsonschema

    n = 0
    for name, schema_name in SCHEMAS.items():
        schema = json.loads((REPO / "docs" / schema_name).read_text())
        for p in root.rglob(name):
            jsonschema.validate(json.loads(p.read_text()), schema)
            n += 1
    return n


@pytest.fixture(scope="module")
def year(tmp_path_factory):
    """The cell's first install, its checks and its update, each as the CLI leaves them."""
    root = tmp_path_factory.mktemp("cell")
    codes = {}
    codes["collect"] = _collect(root / "install", "--seed", SEED, "--views", 8)
    codes["calibrate"] = _cli_reproducible("calibrate", root / "install", "--out", root / "r0")
    # a month later: the same rig, a short check; then a camera bumped by 3 mm / 0.5 deg
    codes["month"] = _collect(root / "month", "--seed", SEED, "--verify-against", root / "r0")
    codes["bumped"] = _collect(root / "bumped", "--seed", SEED, "--verify-against", root / "r0", "--sim-bump", 3, 0.5)
    return root, codes


def test_the_collected_session_calibrates_close_to_its_truth(year):
    root, codes = year
    assert codes["collect"] == 0 and codes["calibrate"] == 0
    res = json.loads((root / "r0" / "result.json").read_text())
    truth = json.loads((root / "install" / "ground_truth.json").read_text())
    rot_deg, trans_mm = pose_error(np.array(res["T_end_cam"]), np.array(truth["T_end_cam"]))
    assert trans_mm < 5 * max(res["refinement"]["sigma_trans_mm"]) + 0.05
    assert rot_deg < 5 * max(res["refinement"]["sigma_rot_deg"]) + 0.01
    sess = yaml.safe_load((root / "install" / "session.yaml").read_text())
    assert sess["collected"]["seed"] == SEED


def _load_export(path: Path, T_expected: np.ndarray) -> None:
    """Parse one exported file with the parser its consumer uses and check it holds the transform."""
    t = T_expected[:3, 3]
    if path.name.endswith(".launch.py"):
        tree = ast.parse(path.read_text())
        numbers = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
        assert any(np.isclose(float(s), t[0], atol=1e-6) for s in numbers if _is_float(s)), path
    elif path.suffix == ".urdf":
        import yourdfpy

        robot = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=False)
        joint = robot.robot.joints[0]
        assert np.allclose(joint.origin[:3, 3], t, atol=1e-6) and np.allclose(
            joint.origin[:3, :3], T_expected[:3, :3], atol=1e-6
        )
    elif path.name.endswith(".urdf.xacro"):
        ET.parse(path)  # well-formed XML
        import xacro

        doc = xacro.parse(path.read_text())
        assert doc.documentElement.tagName == "robot"
    elif path.suffix == ".launch":
        ET.parse(path)
    elif path.suffix in (".yaml", ".calib"):
        d = yaml.safe_load(path.read_text())
        assert isinstance(d, dict) and _holds(d, t[0]), path
    elif path.suffix == ".json":
        d = json.loads(path.read_text())
        assert _holds(d, t[0]), path
    else:
        raise AssertionError(f"unexpected export file {path}")


def _is_float(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def _holds(d, x: float) -> bool:
    """Whether a parsed document holds the number ``x`` (the transform's x translation) somewhere."""
    if isinstance(d, dict):
        return any(_holds(v, x) for v in d.values())
    if isinstance(d, list):
        return any(_holds(v, x) for v in d)
    return isinstance(d, float) and abs(d - x) < 1e-6


def test_every_export_loads_in_its_consumers_parser(year, tmp_path):
    root, _ = year
    res = json.loads((root / "r0" / "result.json").read_text())
    T = np.array(res["T_end_cam"])
    written = []
    for fmt in ("ros2", "urdf", "moveit", "easy_handeye2", "yaml", "json"):
        out = tmp_path / fmt
        out.mkdir()
        assert _cli("export", root / "r0", "--to", fmt, "--out", out) == 0
        written += sorted(out.iterdir())
    assert len(written) >= 9
    for p in written:
        _load_export(p, T)
    # the result folder's own files are never the target of an export
    before = (root / "r0" / "result.json").read_bytes()
    assert _cli("export", root / "r0", "--to", "json", "--out", root / "r0" / "result.json") == 2
    assert (root / "r0" / "result.json").read_bytes() == before


def _month_is_unchanged(month: dict) -> None:
    """The unchanged rig's check: still valid, its verdict follows its p-value, and it sees far less than the bump.

    The check repeats exactly: the installed result's bits do (calibrateCamera on one thread) and the plan's
    choice does not follow its last bits (ties broken by order, a view set's missing information zero, not
    rounding; tests/recal/test_plan.py). Before, the plan's poses changed from run to run while this seed's
    robot noise draw stayed (an unlucky one): statistics of 6.6-29 over 6 dof were several plans of one draw.
    """
    assert month["verdict"] == "still valid" and not month["drifted"], month["headline"]
    assert month["drifted"] is (month["test"]["p_value"] < month["test"]["alpha"])
    assert month["change"]["trans_mm"] < 1.5 and month["change"]["rot_deg"] < 0.15, month["headline"]


def test_a_month_later_the_check_is_valid_and_a_bump_is_drifted(year):
    root, codes = year
    month = json.loads((root / "month" / "verify" / "verify.json").read_text())
    bumped = json.loads((root / "bumped" / "verify" / "verify.json").read_text())
    _month_is_unchanged(month)
    assert codes["month"] == (DRIFTED_EXIT_CODE if month["drifted"] else 0)
    assert codes["bumped"] == DRIFTED_EXIT_CODE and bumped["drifted"] is True and bumped["test"]["p_value"] < 1e-6
    assert 2.0 < bumped["change"]["trans_mm"] < 4.5
    for name in ("month", "bumped"):
        assert yaml.safe_load((root / name / "session.yaml").read_text())["collected"]["seed"] == SEED


def test_the_prior_updates_with_few_views_and_compare_sees_the_bump(year, tmp_path):
    root, _ = year
    # the unchanged rig's few views with the install as prior: the prior holds and the views count with it
    rc = _cli("calibrate", root / "month", "--prior", root / "r0", "--out", tmp_path / "same", "--export", "json")
    same = json.loads((tmp_path / "same" / "result.json").read_text())
    if not same["prior"]["contradicted"]:  # the prior's test is verify's: a false alarm in ~1 check in 20
        assert rc == 0 and same["verdict"] in ("PASS", "WARN"), same["verdict_headline"]
        assert same["prior"]["views_with_prior"] > len([v for v in same["views"] if v.get("used")])
        assert (tmp_path / "same" / "hand_eye.json").exists()
    else:
        assert same["prior"]["used"].startswith("no prior on X")
    # the bumped rig: the prior on X is contradicted and dropped; compare names the drift
    rc = _cli("calibrate", root / "bumped", "--prior", root / "r0", "--out", tmp_path / "moved")
    moved = json.loads((tmp_path / "moved" / "result.json").read_text())
    assert moved["prior"]["contradicted"] is True and rc in (0, QAFailed.exit_code)
    assert _cli("compare", root / "r0", tmp_path / "same") in (0, DRIFTED_EXIT_CODE)
    assert _cli("compare", root / "r0", tmp_path / "moved") == DRIFTED_EXIT_CODE
    assert _validate_tree(tmp_path) >= 4


def _as_check(session: Path, dst: Path, against: Path) -> Path:
    """A collected session copied so that its session.yaml declares the installed result it checks."""
    shutil.copytree(session, dst)
    shutil.rmtree(dst / "verify", ignore_errors=True)
    doc = yaml.safe_load((dst / "session.yaml").read_text())
    doc["verify_against"] = os.path.relpath(against, dst)
    (dst / "session.yaml").write_text(yaml.safe_dump(doc))
    return dst


def test_batch_over_a_mixed_fleet_gives_every_session_a_row(year, tmp_path):
    """The cell's history beside other installs: eye-to-hand, another board, a pose-only tracker session, a
    session that does not load, one with an absurd time stamp, and verify sessions; one row each."""
    from handeye.sim.poses import make_tracker_session
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session
    from handeye.targets import ChessboardSpec

    small = {"n_views": 8, "intrinsics": default_intrinsics(640, 360), "supersample": 2}

    root, _ = year
    fleet = tmp_path / "fleet"
    out = tmp_path / "out"
    shutil.copytree(root / "install", fleet / "cell" / "2026-01-05")
    write_vendor_session(fleet / "cell" / "2026-02-04-e2h", seed=11, mode="eye_to_hand", **small)
    write_vendor_session(fleet / "other" / "2026-01-10", seed=12, target=ChessboardSpec(9, 6, 0.025), **small)
    ts = make_tracker_session(mode="eye_to_hand", n_views=12, seed=2)
    ts.write(fleet / "tracker" / "2026-01-11")
    broken = fleet / "other" / "2026-02-10"
    write_vendor_session(broken, seed=13, **small)
    (broken / "poses.txt").write_text("0.1,0.2,0.3,0.1,0.2\n" * 8)
    stamped = fleet / "other" / "2026-03-10"
    write_vendor_session(stamped, seed=14, **small)
    _to_native(stamped, t_image=1e20)
    _as_check(root / "month", fleet / "cell" / "2026-02-06-check", out / "cell" / "2026-01-05")
    _as_check(root / "bumped", fleet / "cell" / "2026-03-06-check", out / "cell" / "2026-01-05")
    proc = subprocess.run(
        [sys.executable, "-m", "handeye.cli", "batch", str(fleet), "--out", str(out), "--workers", "2", "--no-report"],
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert proc.returncode == QAFailed.exit_code, proc.stdout + proc.stderr[-3000:]
    rows = (out / "fleet.csv").read_text().splitlines()
    sessions = {
        "2026-01-05",
        "2026-02-04-e2h",
        "2026-01-10",
        "2026-01-11",
        "2026-02-10",
        "2026-03-10",
        "2026-02-06-check",
        "2026-03-06-check",
    }
    assert sessions <= {r.split(",")[1] for r in rows[1:]}, rows
    assert (out / "index.html").exists() and (out / "index.md").exists()
    rec = {p.parent.name: json.loads(p.read_text()) for p in out.glob("*/*/batch.json")}
    assert rec["2026-03-06-check"]["verdict"] == "DRIFTED"
    month = json.loads((out / "cell" / "2026-02-06-check" / "verify.json").read_text())
    _month_is_unchanged(month)
    assert rec["2026-02-06-check"]["verdict"] == ("DRIFTED" if month["drifted"] else "VALID")
    assert _validate_tree(out) >= 8
    # the index is rebuilt from the output folder alone, damaged files and all
    (out / "other" / "2026-01-10" / "result.json").write_text(json.dumps({"status": "ok", "verdict": {"x": 1}}))
    proc = subprocess.run(
        [sys.executable, "-m", "handeye.cli", "batch", str(out), "--index-only"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode in (0, QAFailed.exit_code), proc.stderr[-2000:]
    assert "2026-01-10" in (out / "fleet.csv").read_text()


def _to_native(vendor: Path, *, t_image: float) -> None:
    """A vendor session rewritten as session.yaml, with one view's capture time ``t_image``."""
    cfg = yaml.safe_load((vendor / "config.yaml").read_text())["checkerboard_args"]
    lines = [ln for ln in (vendor / "poses.txt").read_text().splitlines() if ln.strip()]
    views = [
        {"id": str(k), "image": f"{k}.jpg", "pose": [float(x) for x in ln.split(",")]}
        for k, ln in enumerate(lines, start=1)
    ]
    views[0]["t_image"] = t_image
    doc = {
        "handeye_session": 1,
        "mode": "eye_in_hand",
        "target": {"type": "chessboard", "inner_corners": [cfg["XX"], cfg["YY"]], "square_m": cfg["L"]},
        "pose_format": {"rotation": "euler"},
        "views": views,
    }
    for name in ("poses.txt", "config.yaml"):
        (vendor / name).unlink()
    (vendor / "session.yaml").write_text(yaml.safe_dump(doc))


def test_a_pose_only_result_goes_through_every_command_that_takes_a_result(tmp_path):
    """A tracker session's result: report, export to every format, compare, apply; verify and --prior
    refuse it in one line (their test works on detected corners)."""
    from handeye.sim.poses import make_tracker_session

    ts = make_tracker_session(mode="eye_to_hand", n_views=14, seed=4)
    ts.write(tmp_path / "tracker", state_sigma=False)
    res_dir = tmp_path / "res"
    assert _cli("calibrate", tmp_path / "tracker", "--out", res_dir, "--no-report") in (0, QAFailed.exit_code)
    res = json.loads((res_dir / "result.json").read_text())
    assert res["refinement"]["validation"]["status"] == "ok" and "cov_x_6x6_verdict" in res["refinement"]
    assert _cli("report", res_dir) == 0 and (res_dir / "report.html").exists()
    T = np.array(res["T_base_cam"])
    for fmt in ("ros2", "urdf", "moveit", "easy_handeye2", "yaml", "json"):
        out = tmp_path / "export" / fmt
        out.mkdir(parents=True)
        assert _cli("export", res_dir, "--to", fmt, "--out", out, "--force") == 0
        for p in out.iterdir():
            _load_export(p, T)
    assert _cli("compare", res_dir, res_dir) == 0
    assert _cli("apply", res_dir, "--point", 0.0, 0.0, 0.5) == 0
    assert _cli("calibrate", tmp_path / "tracker", "--prior", res_dir, "--out", tmp_path / "p") == 2
    assert _validate_tree(tmp_path) >= 1
