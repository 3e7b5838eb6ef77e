"""session.yaml's unknown keys: named with the nearest known key, and none in what handeye writes itself."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from handeye.cell.workflow import read_cell_file
from handeye.collect import session_writer as sw
from handeye.frames import T_from_rotvec
from handeye.session import load_session
from handeye.session.keys import TARGET_KEYS
from handeye.sim.poses import make_tracker_session
from handeye.sim.scenarios import default_intrinsics
from handeye.targets import (
    AprilGridSpec,
    CharucoSpec,
    ChessboardSpec,
    CircleGridSpec,
    MarkerSpec,
    TrackedTargetSpec,
)

POSES = [T_from_rotvec(np.array([0.1 * k, -0.2, 0.3 * k]), np.array([0.4, 0.05 * k, 0.3])) for k in range(1, 5)]


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]


def _session(tmp_path, doc_extra: dict, view_extra: dict) -> tuple:
    d = tmp_path / "s"
    d.mkdir()
    views = []
    for k, T in enumerate(POSES, start=1):
        (d / f"{k}.png").write_bytes(b"x")
        views.append({"id": str(k), "image": f"{k}.png", "pose": T.tolist(), **view_extra.get(k, {})})
    doc = {
        "handeye_session": 1,
        "target": {"type": "charuco", "squares": [5, 7], "square_m": 0.036, "marker_m": 0.018},
        "pose_format": {"rotation": "matrix"},
        "views": views,
        **doc_extra,
    }
    (d / "session.yaml").write_text(yaml.safe_dump(doc))
    return d, d / "session.yaml"


def test_misspelt_session_keys_are_named_with_the_nearest_known_key_and_ignored(tmp_path, caplog):
    intr = {"fx": 900, "fy": 900, "cx": 320, "cy": 240, "image_size": [640, 480], "usage": "prior"}
    d, path = _session(
        tmp_path,
        {"mdoe": "eye_to_hand", "intrinsics": intr, "colour": "red"},
        {2: {"joint": [0.0] * 6}, 3: {"joint": [0.0] * 6}},
    )
    doc = yaml.safe_load(path.read_text())
    doc["target"]["legacy_patern"] = True
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    with caplog.at_level("WARNING", logger="handeye.session.native"):
        s = load_session(d)
    # ignored: the defaults stay in force (as the warnings say)
    assert s.mode == "eye_in_hand" and s.mode_source == "default"
    assert s.intrinsics_prior == "fixed" and s.target.legacy_pattern is False
    said = _warnings(caplog)
    assert [line.split("; known keys")[0] for line in said] == [
        f"{path}: unknown key colour is ignored",
        f"{path}: unknown key mdoe is ignored (did you mean mode?)",
        f"{path}: unknown key intrinsics.usage is ignored (did you mean intrinsics.use?)",
        f"{path}: unknown key target.legacy_patern is ignored (did you mean target.legacy_pattern?)",
        f"{path}: view 2 and 1 other view: unknown key joint is ignored (did you mean joints?)",
    ]
    assert "known keys: intrinsics.model, intrinsics.distortion_model" in said[2]


def test_every_target_writes_only_keys_its_parser_knows():
    specs = [
        ChessboardSpec(11, 8, 0.03),
        CharucoSpec(5, 7, 0.036, 0.018, "DICT_6X6_250", True),
        CircleGridSpec(4, 11, 0.02, asymmetric=True),
        MarkerSpec(0.05, "DICT_APRILTAG_36h11", 3),
        AprilGridSpec(6, 6, 0.025, 0.3, "DICT_APRILTAG_36h11", 0),
        TrackedTargetSpec(),
    ]
    for spec in specs:
        d = spec.to_dict()
        assert set(d) <= set(TARGET_KEYS[d["type"]]), d


def test_a_collected_session_and_a_tracker_session_load_without_an_unknown_key(tmp_path, caplog):
    writer = sw.SessionWriter(
        tmp_path / "c",
        mode="eye_in_hand",
        target=ChessboardSpec(11, 8, 0.03),
        intrinsics=default_intrinsics(640, 360),
        intrinsics_source={"device": "sim"},
        collected={"seed": 1},
    )
    for k, T in enumerate(POSES, start=1):
        extra = {"checks": {"sharpness": 1.0}, "camera_frame": {"exposure": 1}, "joints": [0.1 * k] * 6}
        writer.write_view(str(k), np.zeros((8, 8), np.uint8), T, t_image=k, t_pose=k, robot_state={"a": 1}, extra=extra)
    tracker = make_tracker_session(mode="eye_to_hand", n_views=6, seed=0)
    tracker.write(tmp_path / "t")
    with caplog.at_level("WARNING"):
        collected, tracked = load_session(tmp_path / "c"), load_session(tmp_path / "t")
    assert len(collected.views) == 4 and len(tracked.views) == 6
    assert not [w for w in _warnings(caplog) if "unknown key" in w]


@pytest.mark.parametrize("key", ["collected", "source", "pose_meaning"])
def test_record_keeping_keys_handeye_writes_are_known(tmp_path, caplog, key):
    d, _ = _session(tmp_path, {key: {"tool": "x"}}, {})
    with caplog.at_level("WARNING"):
        load_session(d)
    assert not _warnings(caplog)


def test_cell_yaml_names_its_unknown_keys(tmp_path, caplog):
    (tmp_path / "cell.yaml").write_text("cell:\n  sessions: [cam1, cam2]\n  session: [cam3]\nrobt: ur5e\n")
    with caplog.at_level("WARNING"):
        sessions, robot = read_cell_file(tmp_path)
    assert [p.name for p in sessions] == ["cam1", "cam2"] and robot is None
    assert [line.split("; known keys")[0] for line in _warnings(caplog)] == [
        f"{tmp_path / 'cell.yaml'}: unknown key robt is ignored (did you mean robot?)",
        f"{tmp_path / 'cell.yaml'}: unknown key cell.session is ignored (did you mean cell.sessions?)",
    ]
    caplog.clear()
    (tmp_path / "cell.yaml").write_text("cell:\n  sessions: [cam1, cam2]\nrobot: ur5e\n")
    with caplog.at_level("WARNING"):
        assert read_cell_file(tmp_path)[1] == "ur5e"
    assert not _warnings(caplog)
