"""The scaled pose factor: a tracker whose translations are s x the true ones (handeye.factors.pose)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from handeye.factors.pose import pose_residual, scaled_pose_factor, scaled_pose_residual
from handeye.frames import se3_exp


def _case(seed: int):
    rng = np.random.default_rng(seed)
    T_x, M, T_board = (se3_exp(rng.normal(0.0, 0.5, 6)) for _ in range(3))
    C = np.linalg.inv(T_x) @ M @ T_board @ se3_exp(rng.normal(0.0, 0.05, 6))
    C[:3, 3] *= float(rng.uniform(0.5, 2.0))
    return T_x, M, T_board, C, float(rng.normal(0.0, 0.5))


@pytest.mark.parametrize("seed", range(4))
def test_scaled_residual_jacobians_match_numeric_differences_on_the_manifold(seed):
    T_x, M, T_board, C, ls = _case(seed)
    _, J_x, J_b, J_s = scaled_pose_residual(T_x=T_x, M=M, T_board=T_board, T_cam_board_measured=C, log_scale=ls)

    def r(Tx, Tb, s):
        return scaled_pose_residual(T_x=Tx, M=M, T_board=Tb, T_cam_board_measured=C, log_scale=s, jacobians=False)[0]

    h = 1e-6
    N_x = np.stack(
        [(r(T_x @ se3_exp(h * e), T_board, ls) - r(T_x @ se3_exp(-h * e), T_board, ls)) / (2 * h) for e in np.eye(6)], 1
    )
    N_b = np.stack(
        [(r(T_x, T_board @ se3_exp(h * e), ls) - r(T_x, T_board @ se3_exp(-h * e), ls)) / (2 * h) for e in np.eye(6)], 1
    )
    N_s = ((r(T_x, T_board, ls + h) - r(T_x, T_board, ls - h)) / (2 * h))[:, None]
    # central differences of a smooth map: truncation ~h^2, rounding ~1e-16/h
    assert np.abs(N_x - J_x).max() < 1e-7 and np.abs(N_b - J_b).max() < 1e-7 and np.abs(N_s - J_s).max() < 1e-7
    assert J_s.shape == (6, 1)


def test_a_scale_of_one_is_the_plain_pose_residual_and_the_true_scale_gives_zero():
    T_x, M, T_board, C, _ = _case(7)
    plain = pose_residual(T_x=T_x, M=M, T_board=T_board, T_cam_board_measured=C)
    scaled = scaled_pose_residual(T_x=T_x, M=M, T_board=T_board, T_cam_board_measured=C, log_scale=0.0)
    for a, b in zip(plain, scaled[:3], strict=True):
        assert np.allclose(a, b, atol=1e-15)
    exact = np.linalg.inv(T_x) @ M @ T_board
    exact[:3, 3] *= 1.7
    r = scaled_pose_residual(
        T_x=T_x, M=M, T_board=T_board, T_cam_board_measured=exact, log_scale=np.log(1.7), jacobians=False
    )[0]
    assert np.abs(r).max() < 1e-12


def test_the_custom_factor_evaluates_the_numpy_residual():
    T_x, M, T_board, C, ls = _case(3)
    kx, kb, ks = gtsam.symbol("x", 0), gtsam.symbol("b", 0), gtsam.symbol("s", 0)
    f = scaled_pose_factor(
        key_x=kx, key_board=kb, key_log_scale=ks, M=M, T_cam_board_measured=C, covariance=np.eye(6) * 1e-4
    )
    v = gtsam.Values()
    v.insert(kx, gtsam.Pose3(T_x))
    v.insert(kb, gtsam.Pose3(T_board))
    v.insert(ks, np.array([ls]))
    r = scaled_pose_residual(T_x=T_x, M=M, T_board=T_board, T_cam_board_measured=C, log_scale=ls, jacobians=False)[0]
    assert np.allclose(f.unwhitenedError(v), r, atol=1e-12)
    assert f.error(v) == pytest.approx(0.5 * r @ r / 1e-4, rel=1e-9)
