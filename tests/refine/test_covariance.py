"""The arrow-shaped information of the refinement (handeye.refine.covariance): assembly and inverse."""

from __future__ import annotations

import numpy as np
import pytest

from handeye.refine.covariance import arrow_blocks, arrow_from_jacobians, arrow_solve, robot_prior_parts


def _factors(rng, c: int, n: int):
    """Random whitened linear factors on a core of c unknowns (two variables: 0:4 and 4:c) and n robot blocks."""
    out = []
    for j in range(n):  # a prior on robot block j, one tied to the core's second variable, and a reprojection-like one
        out.append((rng.normal(size=(6, 6)), rng.normal(size=6), [(-1 - j, 6)]))
        out.append((rng.normal(size=(6, 6 + c - 4)), rng.normal(size=6), [(-1 - j, 6), (4, c - 4)]))
        out.append((rng.normal(size=(10, c + 6)), rng.normal(size=10), [(0, 4), (4, c - 4), (-1 - j, 6)]))
    out.append((rng.normal(size=(4, 4)), rng.normal(size=4), [(0, 4)]))
    return out


def _dense(factors, c: int, n: int):
    """Each factor's Jacobian placed in the full (c + 6n) columns, stacked."""
    rows, bs = [], []
    for A, b, slots in factors:
        full, col = np.zeros((A.shape[0], c + 6 * n)), 0
        for o, d in slots:
            at = o if o >= 0 else c + 6 * (-1 - o)
            full[:, at : at + d] = A[:, col : col + d]
            col += d
        rows.append(full)
        bs.append(b)
    return np.vstack(rows), np.concatenate(bs)


def test_arrow_assembly_is_the_dense_normal_equations_and_its_inverse_the_dense_inverse():
    rng = np.random.default_rng(3)
    c, n = 7, 4
    factors = _factors(rng, c, n)
    A, b = _dense(factors, c, n)
    Hcc, Hcp, Hpp, grad, cost = arrow_from_jacobians(factors, c, n)
    H = A.T @ A
    dHcc, dHcp, dHpp = arrow_blocks(H, c, n)
    np.testing.assert_allclose(Hcc, dHcc, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(Hcp, dHcp, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(Hpp, dHpp, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(grad, -A.T @ b, rtol=1e-12, atol=1e-12)  # gradient of |A dx - b|^2 / 2 at 0
    assert cost == pytest.approx(0.5 * b @ b, rel=1e-12)
    S_cc, S_pp, x, S_cp = arrow_solve(Hcc, Hcp, Hpp, -grad, cross=True)
    S = np.linalg.inv(H)
    np.testing.assert_allclose(S_cc, S[:c, :c], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(S_pp, arrow_blocks(S, c, n)[2], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(S_cp, arrow_blocks(S, c, n)[1], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(x, np.linalg.lstsq(A, b, rcond=None)[0], rtol=1e-9, atol=1e-12)


def test_a_factor_on_two_robot_blocks_is_refused():
    rng = np.random.default_rng(4)
    with pytest.raises(ValueError, match="two robot blocks"):
        arrow_from_jacobians([(rng.normal(size=(6, 12)), rng.normal(size=6), [(-1, 6), (-2, 6)])], 3, 2)


@pytest.mark.parametrize("m", [0, 3])
def test_the_robot_priors_parts_of_x_covariance_are_sigma_h_sigma_and_sum_with_the_rest_to_it(m):
    """Each robot-prior group's part of X's covariance is [Sigma H_g Sigma]_xx of the dense problem.

    The parts of all sources (the other factors, two robot-prior groups on ``u_i = p_i - J_i delta`` with m DH
    offsets delta in the core) add up to X's covariance (Sigma H Sigma = Sigma).
    """
    rng = np.random.default_rng(5 + m)
    c, n = 9, 5
    dh = slice(c - m, c)
    A, _ = _dense(_factors(rng, c, n), c, n)
    H_rest = A.T @ A
    J = rng.normal(size=(n, 6, m))
    masks = [np.diag([1.0, 1, 1, 0, 0, 0]), np.diag([0.0, 0, 0, 1, 1, 1])]
    sigmas = (0.3, 2.0)
    W = [np.stack([mk / s**2] * n) for mk, s in zip(masks, sigmas, strict=True)]  # (n, 6, 6) per group
    H_groups = []
    for Wg in W:
        Hg = np.zeros((c + 6 * n, c + 6 * n))
        for i in range(n):
            D = np.zeros((6, c + 6 * n))  # d u_i / d (core, blocks)
            D[:, c + 6 * i : c + 6 * i + 6] = np.eye(6)
            D[:, dh] = -J[i]
            Hg += D.T @ Wg[i] @ D
        H_groups.append(Hg)
    H = H_rest + sum(H_groups)
    S = np.linalg.inv(H)
    Hcc, Hcp, Hpp = arrow_blocks(H, c, n)
    S_cc, _, _, S_cp = arrow_solve(Hcc, Hcp, Hpp, cross=True)
    parts = robot_prior_parts(S_cc, S_cp, J, dh, W)
    for part, Hg in zip(parts, H_groups, strict=True):
        np.testing.assert_allclose(part, (S @ Hg @ S)[:6, :6], rtol=1e-8, atol=1e-12)
    rest = (S @ H_rest @ S)[:6, :6]
    np.testing.assert_allclose(parts.sum(axis=0) + rest, S[:6, :6], rtol=1e-8, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(parts[0]) > 0) and np.all(np.linalg.eigvalsh(parts[1]) > 0)
