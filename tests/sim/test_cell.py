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
