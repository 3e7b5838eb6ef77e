"""X's covariance when the tracker's sigmas are estimated from the views: their degrees of freedom.

The plug-in covariance ``Sigma = inv(J^T W J)`` of a pose-only refinement treats the three estimated sigmas
(rotation; translation across and along the optical axis) as known. Its Wald statistic of X is heavier-tailed
than chi-square(6) for two reasons: the sigmas' own spread (Satterthwaite's F over each group's part
``Sigma_g = s_g^2 Sigma J^T W Q_g W J Sigma``, :func:`covariance_parts`) and the weights they gave the estimate
(a sigma estimated too small overweights its group, so X's error grows where the plug-in says it shrank).
:func:`resampled_factors` takes both: the estimation is repeated on noise drawn at the estimated sigmas, and each
block's factor is the 95 % point of the resampled statistic over that at known sigmas. The plug-in covariance
times that factor has its chi-square(6) ellipsoid right. See docs/uncertainty.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

from ..special import fdtri
from ..stats import chi2_ppf, estimated_parts_region_factor

#: the tracker's noise groups, in the order of the sigmas
GROUPS = ("rot", "trans", "trans_along")
REGION_P = 0.95
#: noise draws of :func:`resampled_factors` (its factors' Monte Carlo error: below 1 % at 20 views)
RESAMPLE_DRAWS = 4000
#: the draws where an arm model's covariance is in the views' (each draw inverts every view's weight)
RESAMPLE_DRAWS_ARM = 1000
#: the draws' seed: the same views give the same covariance
RESAMPLE_SEED = 20261207
#: relative change of the draws' sigmas that ends their variance components: 1e-3 moves a factor by about 1e-3,
#: far inside its Monte Carlo error; at most RESAMPLE_ROUNDS rounds
RESAMPLE_TOL = 1e-3
RESAMPLE_ROUNDS = 100


@dataclass(frozen=True)
class NoiseDof:
    """The estimated sigmas' degrees of freedom and the factor each block's plug-in covariance takes."""

    dof: dict[str, float]  # per estimated noise group: its redundancy
    x_dof: Optional[float] = None  # the F's for X's covariance (:func:`equivalent_dof`); None: every sigma stated
    x_factor: float = 1.0
    board_dof: Optional[float] = None
    board_factor: float = 1.0
    scale_dof: Optional[float] = None  # the tracker's translation scale (13th parameter), when estimated
    scale_factor: float = 1.0
    method: str = ""  # "resampled" (:func:`resampled_factors`), "satterthwaite" where it cannot; "" all stated


def redundancies(sigma: np.ndarray, Q: np.ndarray, W: np.ndarray, J: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(3,) each group's redundancy ``s_g^2 tr(Q_g P)``, ``P = W - W J S J^T W`` (its diagonal blocks).

    ``sigma`` (3,), ``Q`` (3, n, 6, 6) the groups' unit covariances, ``W`` (n, 6, 6) the views' weights,
    ``J`` (n, 6, p) their Jacobians, ``S`` (p, p) the covariance of the parameters.
    """
    WJ = W @ J
    P = W - WJ @ S @ np.swapaxes(WJ, 1, 2)  # shape (n, 6, 6)
    return sigma**2 * np.einsum("gnij,nji->g", Q, P)


def covariance_parts(sigma: np.ndarray, Q: np.ndarray, W: np.ndarray, J: np.ndarray, S: np.ndarray) -> np.ndarray:
    """(3, p, p) each noise group's part ``Sigma_g`` of the parameters' covariance ``S`` (arguments as above)."""
    WJ = W @ J  # shape (n, 6, p)
    inner = np.einsum("nki,gnkl,nlj->gij", WJ, Q, WJ)  # sum over the views of J^T W Q_g W J
    return sigma[:, None, None] ** 2 * (S[None] @ inner @ S[None])


def noise_dof(
    sigma: np.ndarray,
    Q: np.ndarray,
    W: np.ndarray,
    J: np.ndarray,
    S: np.ndarray,
    estimated: Mapping[str, bool],
    *,
    floors: Optional[np.ndarray] = None,
    extra: Optional[np.ndarray] = None,
) -> NoiseDof:
    """The degrees of freedom of the estimated sigmas and the factors of X's, the board's and the scale's blocks.

    X is parameters 0:6, the board 6:12, the tracker's log scale 12 when estimated.

    ``estimated``: group name -> whether its sigma was estimated from the views (an unresolved group's is held,
    as a stated one: known). Arguments as :func:`redundancies`, over the views in the solve; ``extra`` (n,6,6):
    what ``W``'s covariance holds beyond the groups' (an arm model's encoder noise), or None. The factors are
    :func:`resampled_factors`'; ``floors``: the variance components' lower bounds. Where the draws' sigmas
    reach those floors (too few views for three sigmas) the resampling cannot place the 95 % point, and
    Satterthwaite's F over each sigma's part of the covariance (:func:`covariance_parts`) gives the factors
    instead. The blocks' degrees of freedom are the F's with the factor's 95 % point (:func:`equivalent_dof`).
    """
    red = redundancies(sigma, Q, W, J, S)
    dofs = [float(red[g]) if estimated.get(name, False) else None for g, name in enumerate(GROUPS)]
    if not any(d is not None for d in dofs):
        return NoiseDof({})
    dof = {name: d for name, d in zip(GROUPS, dofs, strict=True) if d is not None}
    scaled = S.shape[0] > 12
    held = np.array([d is None for d in dofs])
    floor = np.zeros(3) if floors is None else np.asarray(floors, float)
    factors = resampled_factors(sigma, Q, J, S, held, floor, extra=extra)
    if factors is None:  # the draws' sigmas reach their floors: the sigmas' spread alone (Satterthwaite's F)
        parts = covariance_parts(sigma, Q, W, J, S)

        def block(idx: slice) -> tuple[Optional[float], float]:
            return estimated_parts_region_factor(S[idx, idx], [q[idx, idx] for q in parts], dofs, p=REGION_P)

        (x_dof, x_f), (b_dof, b_f) = block(slice(0, 6)), block(slice(6, 12))
        s_dof, s_f = block(slice(12, 13)) if scaled else (None, 1.0)
        return NoiseDof(dof, x_dof, x_f, b_dof, b_f, s_dof, s_f, "satterthwaite")
    x_f, b_f, s_f = factors
    s_dof = equivalent_dof(s_f, 1) if scaled else None
    return NoiseDof(dof, equivalent_dof(x_f, 6), x_f, equivalent_dof(b_f, 6), b_f, s_dof, s_f, "resampled")


def resampled_factors(
    sigma: np.ndarray,
    Q: np.ndarray,
    J: np.ndarray,
    S: np.ndarray,
    held: np.ndarray,
    floors: np.ndarray,
    *,
    extra: Optional[np.ndarray] = None,
    draws: Optional[int] = None,
    seed: int = RESAMPLE_SEED,
) -> Optional[tuple[float, float, float]]:
    """(X's, the board's, the scale's) factors on the plug-in covariance, from the resampled estimation.

    On the final linearisation (``J`` (n,6,p), ``S`` the plug-in covariance, ``sigma`` the estimated sigmas,
    ``Q`` (3,n,6,6) the groups' unit covariances: orthogonal projections over each view's weight) the views'
    noise is drawn ``draws`` times at ``sigma``, and each draw repeats the estimation: the variance components
    (Foerstner's ``s_g^2 = e^T K_g e / r_g``, at least ``floors``; ``held`` groups stay; a heavy-tailed
    tracker's EM weights, in ``Q``, held) alternating with the weighted solve, then the solve at the final
    sigmas. The rest of the information (a prior) is drawn about the truth with its own covariance. Each block's
    factor is the 95 % point of its Wald statistic under the draw's own plug-in covariance over that of the same
    draws solved at the known sigmas (chi-square's, with the draws' common error cancelled), at least 1 (the
    plug-in is the covariance at known sigmas). The scale's is 1 without a 13th parameter; all three are 1 when
    every group is ``held``. None when, without ``extra``, at least 5 % of the draws take a sigma down to its
    floor: a view's weight then grows without bound, and the 95 % point is the floors', not the data's (too few
    views for three sigmas: 5 or fewer, as measured in docs/uncertainty.md).

    ``extra`` (n,6,6): a known share of every view's covariance (an arm model's encoder noise); the views'
    weights are then inverted per draw (``draws`` default :data:`RESAMPLE_DRAWS_ARM`, the factors' Monte Carlo
    error about 1.5 %); without it they are ``sum_g K_g / s_g^2`` and a draw costs a few p x p operations
    (default :data:`RESAMPLE_DRAWS`).
    """
    if np.all(held):
        return 1.0, 1.0, 1.0
    r = _Resampling(
        np.asarray(sigma, float) ** 2,
        Q,
        J,
        S,
        ~np.asarray(held, bool),
        np.asarray(floors, float) ** 2,
        int(draws or (RESAMPLE_DRAWS if extra is None else RESAMPLE_DRAWS_ARM)),
        np.random.default_rng(seed),
    )
    if extra is not None:  # the encoders' share keeps every view's weight finite, whatever a draw's sigmas
        return _block_factors(*_resampled_with_extra(r, extra)[:3], S)
    d, cov, known, s2 = _resampled_groups(r)
    floored = np.any(r.free[None] & (s2 <= r.floor2[None] * (1.0 + 1e-9)), axis=1)
    if np.mean(floored) >= 1.0 - REGION_P:  # the 95 % point would be the floors', not the data's
        return None
    return _block_factors(d, cov, known, S)


@dataclass(frozen=True)
class _Resampling:
    """What both ways of :func:`resampled_factors` draw from."""

    s2_hat: np.ndarray  # (3,) the estimated variances: the draws' truth
    Q: np.ndarray
    J: np.ndarray
    S: np.ndarray
    free: np.ndarray  # (3,) bool: the groups estimated again on each draw
    floor2: np.ndarray  # (3,) their variances' lower bounds
    draws: int
    rng: np.random.Generator


def _resampled_groups(r: _Resampling) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(errors, plug-in covariances, errors at the known sigmas, variances) of the draws; weights the groups'."""
    Q, J, S, s2_hat, free, floor2, draws, rng = r.Q, r.J, r.S, r.s2_hat, r.free, r.floor2, r.draws, r.rng
    n, p = J.shape[0], J.shape[2]
    w = 6.0 / np.einsum("gnii->n", Q)  # each view's weight: the projections sum to the identity
    K = Q * (w**2)[None, :, None, None]  # the views' weights are sum_g K_g / s_g^2
    A = np.einsum("nki,gnkl,nlj->gij", J, K, J)  # (3, p, p)
    N0 = np.linalg.inv(S) - np.einsum("g,gij->ij", 1.0 / s2_hat, A)  # a prior's information (else ~0)
    N0 = 0.5 * (N0 + N0.T)
    dims = np.einsum("gnii->g", Q * w[None, :, None, None])  # each group's observations: 3n, 2n, n
    # the views' noise at the estimated sigmas, n = sum_g s_g P_g z / sqrt(w) (P_g = w Q_g a projection), enters
    # the estimation through n^T K_g n = s_g^2 z^T P_g z and J^T K_g n = s_g sum_n sqrt(w) J^T P_g z
    P = Q * w[None, :, None, None]
    z = rng.standard_normal((draws, n, 6))
    Pz = np.einsum("gnkl,bnl->bgnk", P, z)  # (draws, 3, n, 6)
    a = s2_hat[None] * np.einsum("bgnk,bnk->bg", Pz, z)  # (draws, 3): n^T K_g n
    Js = (J * np.sqrt(w)[:, None, None]).reshape(n * 6, p)
    b = (Pz.reshape(draws, 3, n * 6) @ Js) * np.sqrt(s2_hat)[None, :, None]  # (draws, 3, p): J^T K_g n
    pull = _prior_pull(N0, rng, draws)

    def solve(s2: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(plug-in covariance, the estimate's error) of the draws ``at`` at their sigmas ``s2``."""
        cov = np.linalg.inv(N0[None] + np.einsum("bg,gij->bij", 1.0 / s2, A))
        return cov, np.einsum("bij,bj->bi", cov, pull[at] - np.einsum("bgi,bg->bi", b[at], 1.0 / s2))

    s2 = np.tile(s2_hat, (draws, 1))
    At = A.transpose(0, 2, 1).reshape(3, p * p).T
    active = np.arange(draws)
    for _ in range(RESAMPLE_ROUNDS):  # each draw until its own sigmas settle
        if not active.size:
            break
        cov, d = solve(s2[active], active)
        dAd = np.stack([np.sum((d @ A[g]) * d, axis=1) for g in range(3)], axis=1)
        quad = a[active] + 2.0 * np.einsum("bi,bgi->bg", d, b[active]) + dAd  # e^T K_g e, e = n + J d
        red = dims[None] - (cov.reshape(len(active), p * p) @ At) / s2[active]
        new = np.where(free[None], np.maximum(quad / np.maximum(red, 1e-12), floor2[None]), s2[active])
        change = _change(new, s2[active])
        s2[active] = new
        active = active[change >= RESAMPLE_TOL]
    cov, d = solve(s2, np.arange(draws))  # each draw's solve at its final sigmas; last, at the known ones
    return d, cov, (pull - np.einsum("bgi,g->bi", b, 1.0 / s2_hat)) @ S.T, s2


def _resampled_with_extra(r: _Resampling, extra: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`_resampled_groups`, with a known ``extra`` in every view's covariance.

    The views' weights are inverted per draw; the variance components are Foerstner's
    ``s_g^2 <- s_g^4 e^T W Q_g W e / r_g`` with ``r_g = s_g^2 tr(Q_g (W - W J S J^T W))``, as the refinement's.
    """
    Q, J, S, s2_hat, free, floor2, draws, rng = r.Q, r.J, r.S, r.s2_hat, r.free, r.floor2, r.draws, r.rng
    n = J.shape[0]
    C_hat = np.einsum("g,gnij->nij", s2_hat, Q) + extra
    W_hat = np.linalg.inv(C_hat)
    N0 = np.linalg.inv(S) - np.einsum("nki,nkl,nlj->ij", J, W_hat, J)  # the DH offsets' prior, a prior on X
    N0 = 0.5 * (N0 + N0.T)
    noise = np.einsum("nij,bnj->bni", np.linalg.cholesky(C_hat), rng.standard_normal((draws, n, 6)))
    pull = _prior_pull(N0, rng, draws)
    Jf = J.reshape(n * 6, -1)  # the views' rows stacked

    def solve(s2: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(weights, weights x J, plug-in covariance, the estimate's error) of the draws ``at`` at ``s2``."""
        W = np.linalg.inv(np.einsum("bg,gnij->bnij", s2, Q) + extra[None])
        WJ = (W @ J[None]).reshape(len(at), n * 6, -1)
        cov = np.linalg.inv(N0[None] + Jf.T[None] @ WJ)
        grad = pull[at] - (np.swapaxes(WJ, 1, 2) @ noise[at].reshape(len(at), n * 6, 1))[..., 0]
        return W, WJ, cov, (cov @ grad[..., None])[..., 0]

    s2 = np.tile(s2_hat, (draws, 1))
    active = np.arange(draws)
    for _ in range(RESAMPLE_ROUNDS):  # each draw until its own sigmas settle
        if not active.size:
            break
        W, WJ, cov, d = solve(s2[active], active)
        e = noise[active] + (d @ Jf.T).reshape(len(active), n, 6)
        We = (W @ e[..., None])[..., 0]
        quad = np.stack([np.sum((We[:, :, None, :] @ Q[g][None])[:, :, 0] * We, axis=(1, 2)) for g in range(3)], 1)
        WJv = WJ.reshape(len(active), n, 6, -1)
        WJSJW = (WJ @ cov).reshape(WJv.shape) @ np.swapaxes(WJv, 2, 3)  # (draws, n, 6, 6)
        red = s2[active] * np.einsum("gnij,bnji->bg", Q, W - WJSJW)  # r_g = s_g^2 tr(Q_g P)
        old = s2[active]
        new = np.where(free[None], np.maximum(old**2 * quad / np.maximum(red, 1e-12), floor2[None]), old)
        s2[active] = new
        active = active[_change(new, old) >= RESAMPLE_TOL]
    _, _, cov, d = solve(s2, np.arange(draws))  # each draw's solve at its final sigmas; last, at the known ones
    return d, cov, (pull - np.einsum("nki,nkl,bnl->bi", J, W_hat, noise)) @ S.T, s2


def _change(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """(draws,) each draw's largest relative change of its sigmas (a sigma at zero: its change from zero)."""
    return np.max(np.abs(np.sqrt(new) - np.sqrt(old)) / np.sqrt(np.maximum(old, np.finfo(float).tiny)), axis=1)


def _prior_pull(N0: np.ndarray, rng: np.random.Generator, draws: int) -> np.ndarray:
    """(draws, p) ``N0 m`` with a prior's mean ``m ~ N(0, N0^+)`` about the truth: ``N0^(1/2) z``.

    ``N0`` is a difference of informations: its directions without a prior hold round-off, negative ones taken
    as 0. The square root is the symmetric one, unique even where a prior's eigenvalues repeat (DH offsets of
    one stated sigma), so the draws change with ``N0`` smoothly, not with which eigenvectors came out.
    """
    ev, V = np.linalg.eigh(N0)
    return rng.standard_normal((draws, len(ev))) @ ((V * np.sqrt(np.clip(ev, 0.0, None))) @ V.T)


def _block_factors(d: np.ndarray, cov: np.ndarray, known: np.ndarray, S: np.ndarray) -> tuple[float, float, float]:
    """(X's, the board's, the scale's) factors of the resampled draws.

    From the draws' errors ``d`` under their plug-in ``cov`` and the same draws' errors ``known`` at the known
    sigmas (covariance ``S``).
    """

    def factor(idx: slice) -> float:
        T = np.einsum("bi,bi->b", d[:, idx], np.linalg.solve(cov[:, idx, idx], d[:, idx, None])[..., 0])
        T0 = np.einsum("bi,bi->b", known[:, idx], np.linalg.solve(S[idx, idx], known[:, idx].T).T)
        # over the same draws' statistic at the known sigmas (chi-square exactly) rather than chi-square's
        # point: the two share the draws, so the ratio's Monte Carlo error is far below either quantile's
        return max(float(np.quantile(T, REGION_P) / np.quantile(T0, REGION_P)), 1.0)

    return factor(slice(0, 6)), factor(slice(6, 12)), factor(slice(12, 13)) if d.shape[1] > 12 else 1.0


def equivalent_dof(factor: float, k: int, p: float = REGION_P) -> Optional[float]:
    """The ``nu`` whose ``k F(k, nu)`` has ``factor`` times chi-square(k)'s ``p`` point; None when ``factor`` is 1."""
    if factor <= 1.0:
        return None
    target = factor * chi2_ppf(p, k)
    if k * fdtri(k, 1e8, p) >= target:
        return 1e8
    lo, hi = np.log(0.1), np.log(1e8)
    for _ in range(60):  # bisection in log(nu): k F(k, nu)'s p point falls as nu grows
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if k * fdtri(k, float(np.exp(mid)), p) > target else (lo, mid)
    return float(np.exp(0.5 * (lo + hi)))
