"""Bad input, class "importers": malformed ViSP and industrial_calibration folders, and an OUT that
already holds a session (refused unless --force). Each case: exit code 2 and the file named."""

from __future__ import annotations

import pytest
import yaml

POSE = [0.5, 0.1, 0.4, 0.1, 0.2, 0.3]


def _visp(src, *, n=3, board="Chessboard: 9 x 6\nsquare size: 0.0236 m\n", pose=None):
    src.mkdir(parents=True, exist_ok=True)
    if board is not None:
        (src / "chessboard-data.txt").write_text(board) if isinstance(board, str) else (
            src / "chessboard-data.txt"
        ).write_bytes(board)
    for k in range(1, n + 1):
        (src / f"image-{k}.png").write_bytes(b"x")
        text = pose if pose is not None else "rows: 6\ncols: 1\ndata:\n" + "".join(f"  - [{v}]\n" for v in POSE)
        (src / f"pose_rPe_{k}.yaml").write_text(text)
    return src


VISP = [
    pytest.param(dict(board=None), ["chessboard-data.txt"], id="no_board_file"),
    pytest.param(dict(board="a board of some size\n"), ["chessboard-data.txt"], id="board_text"),
    pytest.param(dict(board=b"\x00\x01" * 30), ["chessboard-data.txt", "UTF-16"], id="board_binary"),
    pytest.param(dict(n=0), ["no ViSP images"], id="no_images"),
    pytest.param(dict(pose="rows: 6\n"), ["pose_rPe_1.yaml", "vpPoseVector"], id="pose_no_data"),
    pytest.param(dict(pose="data: [1, 2, 3, 4, 5, 6]\n"), ["pose_rPe_1.yaml", "vpPoseVector"], id="pose_flat"),
    pytest.param(
        dict(pose="data: [[a], [b], [c], [d], [e], [f]]\n"), ["pose_rPe_1.yaml", "data[0]"], id="pose_letters"
    ),
    pytest.param(dict(pose="data: [[.nan], [0], [0], [0], [0], [0]]\n"), ["pose_rPe_1.yaml", "data[0]"], id="pose_nan"),
    pytest.param(dict(pose="data: {a: 1}\n"), ["pose_rPe_1.yaml"], id="pose_mapping"),
    pytest.param(dict(pose="- 1\n- 2\n"), ["pose_rPe_1.yaml", "mapping"], id="pose_list"),
    pytest.param(dict(pose="data: [[1]\n"), ["pose_rPe_1.yaml", "YAML"], id="pose_bad_yaml"),
]


def test_visp_missing_pose_file(run_cli, names, tmp_path):
    src = _visp(tmp_path / "visp")
    (src / "pose_rPe_2.yaml").unlink()
    rc, err = run_cli("import", "visp", src, tmp_path / "out")
    assert rc == 2
    names(err, "image-2.png has no pose file")


def test_visp_camera_file_without_parameters(run_cli, names, tmp_path):
    src = _visp(tmp_path / "visp")
    (src / "camera.xml").write_text("<camera><name>x</name></camera>")
    rc, err = run_cli("import", "visp", src, tmp_path / "out", "--given-intrinsics")
    assert rc == 2
    names(err, "camera.xml", "px, py, u0, v0")


def _ical(src, *, data=None, pose=None, finder=None):
    (src / "images").mkdir(parents=True)
    (src / "poses").mkdir()
    (src / "images" / "0.png").write_bytes(b"x")
    (src / "poses" / "0.yaml").write_text(
        yaml.safe_dump(pose if pose is not None else {"x": 0.5, "y": 0.1, "z": 0.4, "qx": 0, "qy": 0, "qz": 0, "qw": 1})
    )
    doc = {
        "data": data if data is not None else [{"image": "images/0.png", "pose": "poses/0.yaml"}],
        "target_finder": finder
        if finder is not None
        else {
            "type": "CharucoGridTargetFinder",
            "cols": 5,
            "rows": 7,
            "chessboard_dim": 0.036,
            "aruco_marker_dim": 0.018,
        },
    }
    (src / "cal_data.yaml").write_text(yaml.safe_dump(doc))
    return src


_CH = {"type": "CharucoGridTargetFinder", "cols": 5, "rows": 7, "chessboard_dim": 0.036, "aruco_marker_dim": 0.018}
ICAL = [
    pytest.param(dict(data=5), ["cal_data.yaml", "no data list"], id="data_number"),
    pytest.param(dict(data=[]), ["cal_data.yaml", "no data list"], id="data_empty"),
    pytest.param(dict(data=["images/0.png"]), ["cal_data.yaml", "data[0]"], id="entry_text"),
    pytest.param(dict(data=[{"image": "images/0.png"}]), ["cal_data.yaml", "data[0]"], id="entry_no_pose"),
    pytest.param(dict(data=[{"image": 3, "pose": "poses/0.yaml"}]), ["cal_data.yaml", "data[0]"], id="image_number"),
    pytest.param(dict(data=[{"image": "images/0.png", "pose": "poses/9.yaml"}]), ["9.yaml"], id="pose_missing"),
    pytest.param(dict(pose={"x": 0.5}), ["0.yaml", "y is not a number"], id="pose_incomplete"),
    pytest.param(
        dict(pose={"x": "a", "y": 0, "z": 0, "qx": 0, "qy": 0, "qz": 0, "qw": 1}), ["0.yaml", "x"], id="pose_letter"
    ),
    pytest.param(dict(finder=[1, 2]), ["cal_data.yaml", "target_finder"], id="finder_list"),
    pytest.param(dict(finder={"type": "DotFinder"}), ["cal_data.yaml", "target finder"], id="finder_unknown"),
    pytest.param(dict(finder={**_CH, "cols": "five"}), ["cal_data.yaml", "target_finder.cols"], id="cols_text"),
    pytest.param(dict(finder={**_CH, "cols": 100000}), ["cal_data.yaml", "target_finder.cols"], id="cols_huge"),
    pytest.param(
        dict(finder={k: v for k, v in _CH.items() if k != "chessboard_dim"}),
        ["cal_data.yaml", "chessboard_dim"],
        id="no_square",
    ),
    pytest.param(
        dict(finder={"type": "ModifiedCircleGridTargetFinder", "cols": 5}),
        ["cal_data.yaml", "rows"],
        id="circles_no_rows",
    ),
]


MAKERS = {"visp": _visp, "ical": _ical}


@pytest.mark.parametrize(
    "kind, kw, culprits",
    [pytest.param("visp", *p.values, id=f"visp-{p.id}") for p in VISP]
    + [pytest.param("ical", *p.values, id=f"ical-{p.id}") for p in ICAL],
)
def test_malformed_source(kind, kw, culprits, run_cli, names, tmp_path):
    src = MAKERS[kind](tmp_path / kind, **kw)
    rc, err = run_cli("import", kind, src, tmp_path / "out" / "session")
    assert rc == 2, err
    names(err, *culprits)
    assert not (tmp_path / "out").exists()  # nor the folders made for it: the same command can run again


def test_ical_without_cal_data(run_cli, names, tmp_path):
    (tmp_path / "ical").mkdir()
    rc, err = run_cli("import", "ical", tmp_path / "ical", tmp_path / "out")
    assert rc == 2
    names(err, "cal_data.yaml")


@pytest.mark.parametrize("existing", ["session.yaml", "poses.txt", "view_records"])
def test_an_existing_session_is_not_overwritten_without_force(existing, run_cli, names, tmp_path):
    src = _visp(tmp_path / "visp")
    out = tmp_path / "out"
    out.mkdir()
    (out / existing).mkdir() if existing == "view_records" else (out / existing).write_text("mine\n")
    rc, err = run_cli("import", "visp", src, out)
    assert rc == 2
    names(err, "already holds a session", existing, "--force")
    if existing != "view_records":
        assert (out / existing).read_text() == "mine\n"
    assert run_cli("import", "visp", src, out, "--force")[0] == 0
    assert (out / "session.yaml").read_text() != "mine\n"


@pytest.mark.parametrize("kind", ["visp", "ical"])
def test_import_out_is_a_file(kind, run_cli, names, tmp_path):
    src = _visp(tmp_path / "src") if kind == "visp" else _ical(tmp_path / "src")
    (tmp_path / "f").write_text("x")
    rc, err = run_cli("import", kind, src, tmp_path / "f")
    assert rc == 2
    names(err, "OUT is a file")


@pytest.mark.parametrize(
    "kind, flags, named",
    [
        ("ical", ["--mode", "eye_to_hand"], "--mode applies to handeye import visp | rosbag | easy_handeye2 | moveit"),
        ("visp", ["--image-topic", "/x"], "--image-topic applies to handeye import rosbag, not visp"),
        ("visp", ["--tracker-sigma", "1", "1"], "--tracker-sigma applies to handeye import easy_handeye2 | moveit"),
        ("ical", ["--given-intrinsics"], "--given-intrinsics applies to handeye import visp, not ical"),
        ("visp", ["--intrinsics-use", "fixed"], "--intrinsics-use applies to handeye import rosbag, not visp"),
    ],
)
def test_an_option_the_importer_would_ignore_is_refused(kind, flags, named, run_cli, names, tmp_path):
    """``import ical SRC OUT --mode eye_to_hand`` wrote the data's eye_in_hand without a word; every option an
    importer does not read was ignored so. One line naming the option and the importers that read it."""
    src = _visp(tmp_path / "src") if kind == "visp" else _ical(tmp_path / "src")
    rc, err = run_cli("import", kind, src, tmp_path / "out", *flags)
    assert rc == 2
    names(err, named)
    assert not (tmp_path / "out").exists()


def test_import_out_is_given_once(run_cli, names, tmp_path):
    """``import moveit S A --out B`` wrote B and left A aside; ``import visp SRC --out B`` asked for OUT."""
    src = _visp(tmp_path / "src")
    rc, err = run_cli("import", "visp", src, tmp_path / "a", "--out", tmp_path / "b")
    assert rc == 2
    names(err, "name two folders for session.yaml")
    assert run_cli("import", "visp", src, "--out", tmp_path / "b")[0] == 0
    assert (tmp_path / "b" / "session.yaml").is_file() and not (tmp_path / "a").exists()
