"""handeye.frames: the one SE(3) module, checked against GTSAM's Pose3 (the convention it states)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from handeye.frames import (
    inv_T,
    is_rotation,
    make_T,
    pose_error,
    se3_adjoint,
    se3_exp,
    se3_log,
    tangent_difference,
    tangent_jacobian,
)


def _random_xi(rng, n=None, *, rot_scale=0.5, trans_scale=0.5):
    shape = (6,) if n is None else (n, 6)
    return rng.normal(size=shape) * np.r_[[rot_scale] * 3, [trans_scale] * 3]


@pytest.mark.parametrize("seed", range(5))
def test_exp_and_log_match_gtsam_pose3(seed):
    rng = np.random.default_rng(seed)
    xi = _random_xi(rng)
    T = se3_exp(xi)
    np.testing.assert_allclose(T, gtsam.Pose3.Expmap(xi).matrix(), atol=1e-12)
    np.testing.assert_allclose(se3_log(T), gtsam.Pose3.Logmap(gtsam.Pose3(T)), atol=1e-12)
    np.testing.assert_allclose(se3_log(T), xi, atol=1e-12)  # |omega| < pi here, so Log inverts Exp


def test_exp_log_near_identity_and_near_pi():
    for omega in ([1e-10, 0, 0], [0, 0, np.pi - 1e-6], [0.3, -0.2, 1e-9]):
        xi = np.r_[omega, 0.1, -0.2, 0.3]
        np.testing.assert_allclose(se3_log(se3_exp(xi)), xi, atol=1e-8)
        np.testing.assert_allclose(se3_exp(xi), gtsam.Pose3.Expmap(xi).matrix(), atol=1e-12)


def test_stacked_inputs_equal_one_by_one():
    rng = np.random.default_rng(7)
    xi = _random_xi(rng, 4)
    T = se3_exp(xi)
    assert T.shape == (4, 4, 4)
    for k in range(4):
        np.testing.assert_allclose(T[k], se3_exp(xi[k]), atol=1e-15)
    np.testing.assert_allclose(se3_log(T), xi, atol=1e-12)


def test_adjoint_moves_a_right_perturbation_to_the_left():
    rng = np.random.default_rng(3)
    T, xi = se3_exp(_random_xi(rng)), 0.1 * _random_xi(rng)
    np.testing.assert_allclose(T @ se3_exp(xi), se3_exp(se3_adjoint(T) @ xi) @ T, atol=1e-12)
    np.testing.assert_allclose(se3_adjoint(T), gtsam.Pose3(T).AdjointMap(), atol=1e-12)


def test_tangent_difference_is_the_right_perturbation():
    rng = np.random.default_rng(4)
    T_a = se3_exp(_random_xi(rng))
    xi = 0.2 * _random_xi(rng)
    T_b = T_a @ se3_exp(xi)
    np.testing.assert_allclose(tangent_difference(T_a, T_b), xi, atol=1e-12)
    np.testing.assert_allclose(tangent_difference(T_a, T_a), np.zeros(6), atol=1e-12)


def test_tangent_jacobian_of_the_translation_is_R_times_the_translation_block():
    """d t(T·Exp(xi)) / d xi = [0, R] at xi = 0 (GTSAM: translation moves along the body axes)."""
    rng = np.random.default_rng(5)
    T = se3_exp(_random_xi(rng))
    J = tangent_jacobian(lambda X: X[:3, 3], T)
    np.testing.assert_allclose(J[:, :3], np.zeros((3, 3)), atol=1e-8)
    np.testing.assert_allclose(J[:, 3:], T[:3, :3], atol=1e-8)


def test_a_tangent_covariance_propagates_like_the_sampled_spread():
    """Sampling T·Exp(xi), xi ~ N(0, S): the translation's covariance is J S J^T to sampling error."""
    rng = np.random.default_rng(6)
    T = make_T(se3_exp(_random_xi(rng))[:3, :3], [0.3, -0.1, 0.5])
    L = np.diag([0.01, 0.02, 0.005, 0.002, 0.001, 0.003])
    S = L @ L
    J = tangent_jacobian(lambda X: X[:3, 3], T)
    xis = rng.normal(size=(20000, 6)) @ L
    t = (T @ se3_exp(xis))[:, :3, 3]
    cov = np.cov(t.T)
    predicted = J @ S @ J.T
    # 20000 samples: relative standard error of a variance ~ sqrt(2/20000) = 1 %; allow 5 sigma
    np.testing.assert_allclose(np.diag(cov), np.diag(predicted), rtol=0.05)


def test_inverse_and_pose_error():
    rng = np.random.default_rng(8)
    T = se3_exp(_random_xi(rng))
    np.testing.assert_allclose(T @ inv_T(T), np.eye(4), atol=1e-12)
    assert is_rotation(T[:3, :3])
    rot_deg, trans_mm = pose_error(T @ make_T(se3_exp(np.r_[0, 0, np.radians(2.0), 0, 0, 0])[:3, :3], [0.003, 0, 0]), T)
    assert rot_deg == pytest.approx(2.0, abs=1e-9)
    assert trans_mm == pytest.approx(3.0, abs=1e-6)


def test_not_a_rotation_is_refused():
    assert not is_rotation(np.diag([1.0, 1.0, -1.0]))  # a reflection
    assert not is_rotation(np.full((3, 3), np.nan))
    assert not is_rotation(np.eye(4))


def test_rotation_forms_agree_with_scipy_including_near_pi_and_zero():
    from scipy.spatial.transform import Rotation

    from handeye.frames import R_from_quat_wxyz, R_from_rotvec, quat_wxyz_from_R, rotvec_from_R

    rv = np.concatenate(
        [
            Rotation.random(300, random_state=2).as_rotvec(),
            [[np.pi - 1e-7, 0, 0], [0, 1e-12, 0], [0, 0, 0], [0.3, 0.2, 2.5]],
        ]
    )
    R = Rotation.from_rotvec(rv).as_matrix()
    np.testing.assert_allclose(R_from_rotvec(rv), R, atol=1e-14)
    np.testing.assert_allclose(R_from_rotvec(rotvec_from_R(R)), R, atol=1e-12)
    away = np.linalg.norm(rv, axis=1) < np.pi - 1e-3  # at pi the sign of the axis is a choice
    np.testing.assert_allclose(rotvec_from_R(R)[away], rv[away], atol=1e-12)
    q = quat_wxyz_from_R(R)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(R_from_quat_wxyz(q), R, atol=1e-14)
    q_ref = Rotation.from_matrix(R).as_quat()[:, [3, 0, 1, 2]]
    q_ref *= np.where(q_ref[:, :1] < 0, -1, 1)
    np.testing.assert_allclose(np.abs(np.sum(q * q_ref, axis=1)), 1.0, atol=1e-12)
    # one rotation at a time (the scalar path) gives the stacked path's quaternion, bit for bit
    np.testing.assert_array_equal(np.array([quat_wxyz_from_R(Rk) for Rk in R]), q)
    half_turns = R_from_rotvec(np.pi * np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [0.6, 0.8, 0]]))
    np.testing.assert_array_equal(np.array([quat_wxyz_from_R(Rk) for Rk in half_turns]), quat_wxyz_from_R(half_turns))
