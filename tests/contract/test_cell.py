"""The cell form of result.json: several cameras of one arm in one file (``kind: cell``)."""

import json

import numpy as np
import pytest

from handeye.contract import read_result, single_camera, validate_result
from handeye.errors import InputError


def _cell(results) -> dict:
    """A cell dict made of two real one-camera results (an image session and a pose-only one)."""
    cams = {}
    for name, folder in (("wrist", results["images"]), ("fixed.1", results["pose_only"])):
        entry = json.loads((folder / "result.json").read_text())
        entry.pop("handeye_result")
        cams[name] = entry
    T_a, T_b = (np.asarray(cams[n][cams[n]["hand_eye"]["name"]]) for n in cams)
    return {
        "handeye_result": 1,
        "kind": "cell",
        "status": "ok",
        "mode": "cell",
        "cameras": cams,
        "camera_pairs": {
            "wrist/fixed.1": {
                "name": "T_wrist_fixed.1",
                "matrix": (np.linalg.inv(T_a) @ T_b).tolist(),
                "cov_6x6": np.eye(6).tolist(),
            }
        },
        "joint_covariance": {
            "blocks": ["cameras.wrist.T_end_cam", "cameras.fixed.1.T_base_cam"],
            "sizes": [6, 6],
            "matrix": np.eye(12).tolist(),
        },
    }


def test_a_cell_reads_and_each_camera_is_a_one_camera_result(results, tmp_path):
    (tmp_path / "result.json").write_text(json.dumps(_cell(results)))
    res = read_result(tmp_path)
    assert res.is_cell and res.camera_names == ["wrist", "fixed.1"]
    assert res.T_x is None  # a cell has no single X
    wrist = single_camera(res, "wrist")
    solo = read_result(results["images"])
    assert not wrist.is_cell and wrist.mode == solo.mode and wrist.x_name == "T_end_cam"
    np.testing.assert_array_equal(wrist.T_x, solo.T_x)
    np.testing.assert_array_equal(wrist.cov_x[0], solo.cov_x[0])
    assert single_camera(res, "fixed.1").x_name == "T_base_cam"


def test_a_cell_without_a_camera_choice_names_its_cameras(results):
    res = validate_result(_cell(results))
    with pytest.raises(InputError, match=r"a cell of 2 cameras \(wrist, fixed.1\)") as e:
        single_camera(res)
    assert "--camera" in str(e.value)
    with pytest.raises(InputError, match="has no camera 'cam9'"):
        single_camera(res, "cam9")
    one = read_result(results["images"])
    assert single_camera(one) is one
    with pytest.raises(InputError, match="not a cell"):
        single_camera(one, "wrist")


@pytest.mark.parametrize(
    "change, words",
    [
        (lambda d: d.update(mode="eye_in_hand"), "mode is 'eye_in_hand' in a cell"),
        (lambda d: d.update(cameras={}), "cameras is missing or empty"),
        (lambda d: d["cameras"].update({"cam 2": d["cameras"]["wrist"]}), "cameras.cam 2"),
        (lambda d: d["cameras"]["wrist"].update(T_end_cam=np.zeros((4, 4)).tolist()), "cameras.wrist.T_end_cam"),
        (lambda d: d["cameras"]["wrist"].pop("T_end_cam"), "cameras.wrist.T_end_cam is missing"),
        (lambda d: d["camera_pairs"]["wrist/fixed.1"].update(name="T_a_b"), "camera_pairs.wrist/fixed.1.name"),
        (lambda d: d.update(camera_pairs={"wrist/cam9": d["camera_pairs"]["wrist/fixed.1"]}), "names 'wrist/cam9'"),
        (lambda d: d["joint_covariance"].update(sizes=[6, 5]), "joint_covariance.matrix is 12x12"),
        (lambda d: d["joint_covariance"].update(matrix=(-np.eye(12)).tolist()), "joint_covariance.matrix"),
    ],
)
def test_a_damaged_cell_is_one_line_naming_the_field(change, words, results):
    d = _cell(results)
    change(d)
    with pytest.raises(InputError, match="damaged") as e:
        validate_result(d)
    assert words in str(e.value) and "\n" not in str(e.value)
