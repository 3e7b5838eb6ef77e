"""Simulated cells (handeye.sim.cell): the same robot poses in every camera, each camera's board where it looks."""

import numpy as np
import pytest

from handeye.errors import ConfigError
from handeye.frames import inv_T
from handeye.sim.cell import make_cell, truth_dict


def test_a_cell_shares_its_view_ids_robot_poses_and_flange_board():
    cell = make_cell(4, n_views=15, seed=3)
    assert cell.names == ("cam1", "cam2", "cam3", "wrist")
    assert [s.mode for s in cell.sessions] == ["eye_to_hand"] * 3 + ["eye_in_hand"]
    first = cell.sessions[0]
    for s in cell.sessions:
        assert s.view_ids == first.view_ids
        np.testing.assert_array_equal(s.T_base_end_true, first.T_base_end_true)
        np.testing.assert_array_equal(s.T_base_end_reported, first.T_base_end_reported)
        np.testing.assert_array_equal(s.joints_encoder, first.joints_encoder)  # one arm, its error shared
        seen = [len(ids) > 0 for ids in s.corner_ids]
        assert sum(seen) >= 0.6 * s.n_views
        assert {v for v, ok in zip(s.view_ids, seen, strict=True) if not ok} == set(s.hidden_view_ids)
    for s in cell.sessions[1:3]:
        np.testing.assert_array_equal(s.T_board_true, first.T_board_true)  # the one flange board
        assert np.linalg.norm(s.T_x_true[:3, 3] - first.T_x_true[:3, 3]) > 0.2  # another place in the cell
    # the corners are the projections through the truth
    s = cell.session("cam2")
    k = next(i for i, ids in enumerate(s.corner_ids) if len(ids))
    T_cb = inv_T(s.T_x_true) @ s.T_base_end_true[k] @ s.T_board_true
    from handeye.camera import pixels_from_board_points

    uv = pixels_from_board_points(T_cb, s.target.object_points(), s.intrinsics)
    assert np.abs(uv - s.image_points[k]).max() < 5 * 0.3 + 1e-9


def test_the_cell_truth_names_every_pair_of_fixed_cameras():
    cell = make_cell(3, n_views=10, seed=0)
    t = truth_dict(cell)
    assert list(t["camera_pairs"]) == ["cam1/cam2"]
    T = np.asarray(t["camera_pairs"]["cam1/cam2"]["matrix"])
    np.testing.assert_allclose(T, inv_T(cell.sessions[0].T_x_true) @ cell.sessions[1].T_x_true)
    assert set(t["cameras"]["wrist"]) == {"mode", "T_end_cam", "T_base_board"}


def test_a_cell_has_two_to_four_cameras():
    with pytest.raises(ConfigError, match="2-4 cameras"):
        make_cell(5)


def _flange_seen(s, k: int) -> np.ndarray:
    """The flange pose camera session ``s`` saw in view k: the one that reprojects its corners exactly."""
    from handeye.camera import pixels_from_board_points
    from handeye.frames import se3_exp

    obj, pts = s.target.object_points()[s.corner_ids[k]], s.image_points[k]

    def r(T: np.ndarray) -> np.ndarray:
        return (pixels_from_board_points(inv_T(s.T_x_true) @ T @ s.T_board_true, obj, s.intrinsics) - pts).ravel()

    T = s.T_base_end_true[k].copy()
    for _ in range(10):  # Gauss-Newton from the truth, numeric Jacobian
        J = np.stack([(r(T @ se3_exp(e)) - r(T @ se3_exp(-e))) / 2e-7 for e in 1e-7 * np.eye(6)], axis=1)
        T = T @ se3_exp(-np.linalg.lstsq(J, r(T), rcond=None)[0])
    return T


def test_view_jitter_moves_each_fixed_cameras_view_of_the_flange_by_its_own_draw():
    """Each fixed camera sees the flange of a view at its own pose; the truth and the wrist camera stay."""
    from handeye.frames import tangent_difference

    plain = make_cell(3, n_views=8, seed=1, noise_px=0.0)
    moved = make_cell(3, n_views=8, seed=1, noise_px=0.0, view_jitter=(0.1, 0.2))
    for a, b in zip(plain.sessions, moved.sessions, strict=True):
        np.testing.assert_array_equal(a.T_base_end_true, b.T_base_end_true)
        np.testing.assert_array_equal(a.T_x_true, b.T_x_true)
    np.testing.assert_array_equal(plain.session("wrist").image_points[0], moved.session("wrist").image_points[0])
    dev = np.array(
        [
            tangent_difference(s.T_base_end_true[k], _flange_seen(s, k))
            for s in (moved.session("cam1"), moved.session("cam2"))
            for k, pts in enumerate(s.image_points)
            if len(pts)
        ]
    )
    assert np.degrees(np.sqrt(np.mean(dev[:, :3] ** 2))) == pytest.approx(0.1, rel=0.4)
    assert 1e3 * np.sqrt(np.mean(dev[:, 3:] ** 2)) == pytest.approx(0.2, rel=0.4)
