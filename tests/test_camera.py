"""handeye.camera: THE projection, against OpenCV's projectPoints (the oracle) and its own Jacobians."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from handeye.camera import Intrinsics, pixels_from_board_points, pixels_from_cam_points
from handeye.frames import make_T, se3_exp

INTR = Intrinsics(910.0, 905.0, 641.0, 362.0, (0.10, -0.25, 1e-3, 8e-4, 0.10), 1280, 720)


def _points(rng, n=40):
    return np.c_[rng.uniform(-0.3, 0.3, (n, 2)), rng.uniform(0.4, 1.2, n)]


@pytest.mark.parametrize("seed", range(3))
def test_projection_equals_cv2_project_points(seed):
    rng = np.random.default_rng(seed)
    p = _points(rng)
    uv, _, _ = pixels_from_cam_points(INTR.as_vector(), p, jacobians=False)
    ref = cv2.projectPoints(p, np.zeros(3), np.zeros(3), INTR.K, INTR.dist_array)[0].reshape(-1, 2)
    np.testing.assert_allclose(uv, ref, atol=1e-9)


def test_board_points_go_through_the_pose():
    rng = np.random.default_rng(1)
    T_cam_board = make_T(se3_exp(np.r_[0.2, -0.1, 0.3, 0, 0, 0])[:3, :3], [0.05, -0.02, 0.7])
    p_board = np.c_[rng.uniform(0, 0.3, (30, 2)), np.zeros(30)]
    rvec = cv2.Rodrigues(T_cam_board[:3, :3])[0]
    ref = cv2.projectPoints(p_board, rvec, T_cam_board[:3, 3], INTR.K, INTR.dist_array)[0].reshape(-1, 2)
    np.testing.assert_allclose(pixels_from_board_points(T_cam_board, p_board, INTR), ref, atol=1e-9)


def test_jacobians_match_central_differences():
    rng = np.random.default_rng(2)
    p = _points(rng, 5)
    k = INTR.as_vector()
    _, J_p, J_k = pixels_from_cam_points(k, p)
    h = 1e-6
    for a in range(3):
        d = np.zeros(3)
        d[a] = h
        num = (
            pixels_from_cam_points(k, p + d, jacobians=False)[0] - pixels_from_cam_points(k, p - d, jacobians=False)[0]
        ) / (2 * h)
        np.testing.assert_allclose(J_p[:, :, a], num, rtol=1e-6, atol=1e-4)
    for a in range(9):
        step = h * max(1.0, abs(k[a]))
        d = np.zeros(9)
        d[a] = step
        num = (
            pixels_from_cam_points(k + d, p, jacobians=False)[0] - pixels_from_cam_points(k - d, p, jacobians=False)[0]
        ) / (2 * step)
        np.testing.assert_allclose(J_k[:, :, a], num, rtol=1e-6, atol=1e-4)


def test_intrinsics_vector_round_trip():
    v = INTR.as_vector()
    assert Intrinsics.from_vector(v, 1280, 720) == INTR
    assert Intrinsics.from_K(INTR.K, INTR.dist_array, 1280, 720) == INTR
