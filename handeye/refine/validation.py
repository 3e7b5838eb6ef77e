"""The validated covariance of a refined result and the verdict covariance that the printed sigmas use.

Refits without some of the views (leave-one-out or interleaved folds, :func:`handeye.refine.refit`)
give a jackknife covariance, shrunk toward the model's shape: the validated covariance. A test of
each fold against what the model predicts for it decides whether the model covariance is too small;
only then is the verdict covariance the larger of the two along every direction. The same folds
serve the diagnostics' cross-validation, and the odd and even halves are refitted for the report.

See docs/uncertainty.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Optional, Sequence, Union

import numpy as np

from ..camera import INTRINSIC_NAMES
from ..config import load_preset
from ..frames import tangent_difference
from ..stats import chi2_sf
from .result import RefineResult

if TYPE_CHECKING:  # the type only: validate imports refit where it runs it
    from .refitting import Refit

log = logging.getLogger(__name__)

SIGMA_RULE = (
    "verdict covariance = the model covariance M unless the folds reject it (each fold's displacement "
    "against the covariance the model predicts for it, chi-square at validation.alpha); then the "
    "generalised-eigenvalue maximum of "
    "the model and the validated covariance: C = L U max(Lambda, 1) U^T L^T with M = L L^T and "
    "L^-1 V L^-T = U Lambda U^T, so that u^T C u >= max(u^T M u, u^T V u) along every direction u"
)


def settings() -> dict[str, Any]:
    """``validation:`` of configs/diagnostics.yaml (fold scheme, minimum views, ratio test level)."""
    return load_preset("diagnostics")["validation"]


# ------------------------------------------------------------------------------ pure math
def fold_indices(n: int, *, loo_max_views: int, folds: int) -> list[np.ndarray]:
    """Index arrays of the held-out views of each fold.

    One view each up to ``loo_max_views`` views, else ``folds`` interleaved groups (view k in fold k
    mod folds).
    """
    if n <= loo_max_views:
        return [np.array([i]) for i in range(n)]
    return [np.arange(f, n, folds) for f in range(folds)]


def jackknife_covariance(thetas: np.ndarray) -> np.ndarray:
    """Grouped jackknife covariance (D,D) of K fold estimates ``thetas``.

    Grouped jackknife covariance (D,D) of K fold estimates ``thetas`` (K,D) of folds that partition
    the units: ``(K - 1) / K · sum_k (theta_k - mean)(theta_k - mean)^T``.
    """
    x = np.asarray(thetas, float)
    K = x.shape[0]
    dev = x - x.mean(axis=0)
    return (K - 1) / K * dev.T @ dev


def shrunk_jackknife(thetas: np.ndarray, cov_model: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(validated covariance, shrinkage intensity, scale): the shrunk, whitened jackknife covariance.

    (validated covariance (D,D), shrinkage intensity in [0, 1], scale s): the jackknife covariance of
    ``thetas`` (K,D), whitened by ``cov_model``, shrunk toward ``s · I`` with the Ledoit-Wolf intensity
    estimated from the K folds, and mapped back. ``s = tr(M^-1 S) / D``: the spread over the model's
    prediction, averaged over the D directions.
    """
    x = np.asarray(thetas, float)
    K, D = x.shape
    L = np.linalg.cholesky(0.5 * (cov_model + cov_model.T))
    y = np.sqrt(K - 1.0) * np.linalg.solve(L, (x - x.mean(axis=0)).T).T  # shape (K, D): S_w = y^T y / K
    S = y.T @ y / K
    s = float(np.trace(S) / D)
    d2 = float(np.sum((S - s * np.eye(D)) ** 2))
    b2 = float(np.mean([np.sum((np.outer(v, v) - S) ** 2) for v in y]) / K)
    rho = 1.0 if d2 <= 0.0 else min(b2, d2) / d2
    W = rho * s * np.eye(D) + (1.0 - rho) * S
    return L @ W @ L.T, rho, s


def generalised_max(cov_model: np.ndarray, cov_other: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C, generalised eigenvalues of ``cov_other`` against ``cov_model`` (D,), ascending).

    The smallest covariance of the form ``L U diag(c) U^T L^T`` with ``u^T C u >= max(u^T M u, u^T V
    u)`` along every direction (:data:`SIGMA_RULE`).
    """
    M = 0.5 * (cov_model + cov_model.T)
    L = np.linalg.cholesky(M)
    W = np.linalg.solve(L, np.linalg.solve(L, 0.5 * (cov_other + cov_other.T)).T)
    lam, U = np.linalg.eigh(0.5 * (W + W.T))
    C = L @ (U * np.maximum(lam, 1.0)) @ U.T @ L.T
    return 0.5 * (C + C.T), lam


def fold_information_statistic(
    deltas: np.ndarray, fold_covs: Sequence[np.ndarray], cov_all: np.ndarray, *, floor: float
) -> tuple[float, float]:
    """(T, dof) of the folds' displacements from the all-views refit against their covariances.

    (T, dof) of the folds' displacements ``deltas`` (K,D) from the all-views refit against their model
    covariances ``P_k = fold_covs[k] - cov_all`` (module docstring): ``T = (K - 1) / K · sum_k delta_k^T P_k^+
    delta_k`` over the directions (generalised eigenvectors against ``cov_all``) in which ``P_k`` exceeds
    ``floor`` times ``cov_all``, ``dof = (K - 1) / K`` times their number. chi-square(dof) if the model is
    right (exactly, for a linear Gaussian model and leave-one-out of independent views, in expectation).
    """
    d = np.asarray(deltas, float)
    K = d.shape[0]
    L = np.linalg.cholesky(0.5 * (cov_all + cov_all.T))
    T, n = 0.0, 0
    for dk, Ck in zip(d, fold_covs, strict=False):
        Pw = np.linalg.solve(L, np.linalg.solve(L, np.asarray(Ck, float) - cov_all).T)
        w, U = np.linalg.eigh(0.5 * (Pw + Pw.T))
        z = U.T @ np.linalg.solve(L, dk)
        keep = w > floor
        T += float(np.sum(z[keep] ** 2 / w[keep]))
        n += int(keep.sum())
    return (K - 1) / K * T, (K - 1) / K * n


def trace_p_value(scale: float, k_folds: int, dim: int) -> float:
    """Upper tail probability of the folds' spread if the model covariance is right.

    Upper tail probability of the folds' spread ``scale = tr(M^-1 S) / D`` if the model covariance is
    right: ``(K - 1) D · scale`` is chi-square with ``(K - 1) D`` degrees of freedom.
    """
    dof = max(int(k_folds) - 1, 1) * int(dim)
    return chi2_sf(dof * float(scale), dof)


def mahalanobis2(delta: np.ndarray, cov: np.ndarray) -> float:
    """``delta^T cov^-1 delta`` (NaN when cov is singular)."""
    try:
        return float(delta @ np.linalg.solve(cov, delta))
    except np.linalg.LinAlgError:
        return float("nan")


# ------------------------------------------------------------------------------ the stage
@dataclass(frozen=True)
class Block:
    """One parameter block (``x``: T_x in the tangent of cov_x_6x6; ``intrinsics``: the free ones)."""

    names: tuple[Any, ...]
    cov_model: np.ndarray
    cov_validated: np.ndarray
    cov_verdict: np.ndarray
    eig: np.ndarray  # generalised eigenvalues of the validated against the model covariance, ascending
    shrinkage: float
    scale: float  # tr(M^-1 S) / D: the folds' spread over the model's, averaged over the directions
    p_value: float  # of the folds' displacements if the model is right (the finding's test)
    finding: bool  # p_value below validation.alpha: the verdict takes the validated covariance where larger
    test: str = "fold information"  # fold information | trace (no fold covariances: equal leverage assumed) |
    # none (the intrinsics without the folds' covariances: not tested, p_value NaN, the model stands)
    model_form: str = "full"  # full | sigmas: the model covariance of the verdict (sigmas: its diagonal)
    # generalised eigenvalues of the raw (unshrunk) jackknife against the model, ascending: the spread's ratio
    # squared along each whitened direction. ``eig`` is the shrunk one's: toward the average, the verdict's
    eig_spread: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def source(self) -> str:
        """Model | validated | model+validated: which covariance the verdict takes in which directions."""
        above = self.eig > 1.0
        if not self.finding or not above.any():
            return "model"
        return "validated" if above.all() else "model+validated"


@dataclass(frozen=True)
class Validation:
    """Outcome of :func:`validate`. ``status`` ok | not_run (``reason`` says why)."""

    status: str
    reason: str = ""
    scheme: str = ""
    view_ids: tuple[Any, ...] = ()  # the used views, in view order
    folds: tuple[Any, ...] = ()  # per fold, the held-out view ids
    refits: tuple[Any, ...] = ()  # per fold, the Refit (status ok or failed)
    x: Optional[Block] = None
    intrinsics: Optional[Block] = None
    halves: dict[str, Any] = field(default_factory=dict)  # "odd" | "even" -> Refit

    @property
    def n_solved(self) -> int:
        return sum(r.status == "ok" for r in self.refits)

    def summary(self) -> str:
        if self.status != "ok":
            return f"not run: {self.reason}"
        assert self.x is not None, "a validation that ran has its X block"
        rms = np.sqrt(max(float(self.x.scale), 0.0))
        # the worst direction of the folds' own spread: the shrunk covariance's (eig) is pulled toward the average
        worst = (
            f" (up to {np.sqrt(max(float(self.x.eig_spread.max()), 0.0)):.2f}x along the worst)"
            if self.x.eig_spread.size
            else ""
        )
        test = (
            f"beyond chance (p = {self.x.p_value:.2g})"
            if self.x.finding
            else f"within chance (p = {self.x.p_value:.2g})"
        )
        return (
            f"{self.scheme}, {self.n_solved}/{len(self.folds)} folds: the held-out spread is {rms:.2f}x the "
            f"model's sigma on average over the six directions the model covariance whitens{worst}, "
            f"{test}; the verdict uses the {self.x.source} covariance"
        )


def validate(
    result: RefineResult,
    *,
    object_points: Optional[np.ndarray] = None,
    views: Sequence[Any],
    halves: bool = True,
    refit_views: Optional[Callable[[list[Any], bool], Refit]] = None,
) -> Validation:
    """Validated and verdict covariances of ``result`` from refits on some of its views.

    ``views``: the refinement's views (those it did not use are left out of the folds, robot-excluded
    views stay in every fold). ``halves``: also refit the odd and even halves of the used views.
    ``refit_views(views, covariance)`` solves the refinement again on a subset; the default is
    :func:`handeye.refine.refit` with ``object_points`` (image views; every fold's first step from one
    linearisation at the full solution, :class:`handeye.refine.refitting.Refitter`); pose-only results pass
    :func:`handeye.refine.poseonly.refit_poses`. See the module docstring for the method.
    """
    cfg = settings()
    if result.status != "ok":
        return Validation("not_run", "the refinement did not succeed")
    pv = result.per_view
    used = [v for v in views if pv.get(v.view_id, {}).get("status") == "used"]
    kept = [v for v in views if pv.get(v.view_id, {}).get("status") == "robot_excluded"]
    if refit_views is None:
        from .refitting import Refitter

        if object_points is None:
            raise ValueError("validate() of image views needs their object_points")
        refitter = Refitter(result, object_points=object_points, views=used + kept)  # one linearisation for all

        def refit_views(sub: list[Any], covariance: bool = True) -> Refit:
            return refitter.refit(sub, covariance=covariance)

    n = len(used)
    ids = tuple(v.view_id for v in used)
    if n < int(cfg["min_views"]):
        return Validation("not_run", f"{n} used views (needs {cfg['min_views']})", view_ids=ids)
    fold_list = fold_indices(n, loo_max_views=int(cfg["loo_max_views"]), folds=int(cfg["folds"]))
    scheme = "leave-one-out" if len(fold_list) == n else f"{len(fold_list)}-fold (interleaved)"
    refits = []
    for f in fold_list:
        out = set(f.tolist())
        refits.append(refit_views([v for k, v in enumerate(used) if k not in out] + kept, True))
    folds = tuple(tuple(ids[i] for i in f) for f in fold_list)
    half = {}
    if halves:
        for name, start in (("odd", 0), ("even", 1)):
            sub = used[start::2]
            if len(sub) >= 3:
                half[name] = refit_views(sub + kept, False)
    ok = [r for r in refits if r.status == "ok"]
    base: dict[str, Any] = dict(scheme=scheme, view_ids=ids, folds=folds, refits=tuple(refits), halves=half)
    if len(ok) < max(3, len(fold_list) // 2 + 1):
        return Validation("not_run", f"only {len(ok)} of {len(fold_list)} folds could be solved", **base)
    # the reference of the finding's test: all views, refitted as the folds are
    every = refit_views(used + kept, True)
    floor = float(cfg["information_floor"])
    try:
        test = _fold_test(
            ok,
            every,
            lambda r: tangent_difference(every.T_x, r.T_x),  # type: ignore[arg-type]  # solved refits have T_x
            lambda r: r.cov_x,
            floor,
        )
        xb = _block(
            ("rx", "ry", "rz", "tx", "ty", "tz"),
            result.cov_x_6x6,
            np.stack([tangent_difference(result.T_x, r.T_x) for r in ok]),  # type: ignore[arg-type]  # solved: T_x
            test=test,
        )
        names = tuple(k for k in INTRINSIC_NAMES if k in result.intrinsics_sigma)
        kb = None
        if names:
            idx = [INTRINSIC_NAMES.index(k) for k in names]
            assert result.intrinsics is not None, "free intrinsics have sigmas only with intrinsics"
            k0 = result.intrinsics.as_vector()[idx]
            M_k, form = intrinsics_model_covariance(result, names)
            test = _fold_test(
                ok,
                every,
                lambda r: r.intrinsics.as_vector()[idx] - every.intrinsics.as_vector()[idx],  # type: ignore[union-attr]
                lambda r: r.cov_intrinsics,
                floor,
            )
            # no trace test for the intrinsics: their jackknife is far from the model's even when it holds (the
            # views inform the distortion very unequally), so without the folds' own covariances the model stands
            kb = _block(
                names,
                M_k,
                np.stack([r.intrinsics.as_vector()[idx] - k0 for r in ok]),  # type: ignore[union-attr]  # solved
                model_form=form,
                test=test if test is not None else "none",
            )
    except np.linalg.LinAlgError as e:  # a model covariance that is not positive definite
        return Validation("not_run", f"covariance not positive definite ({e})", **base)
    return Validation("ok", "", x=xb, intrinsics=kb, **base)


def _fold_test(
    ok: list[Refit],
    every: Refit,
    delta: Callable[[Refit], np.ndarray],
    cov: Callable[[Refit], Optional[np.ndarray]],
    floor: float,
) -> Optional[tuple[float, float]]:
    """(T, dof) of :func:`fold_information_statistic` over the solved folds that have their own covariance.

    (T, dof) of :func:`fold_information_statistic` over the solved folds that have their own covariance
    (``delta(refit)``: its displacement from the all-views refit ``every``; ``cov(refit)``: its covariance),
    or None when no test is possible (the all-views refit failed or has no usable covariance, or fewer than
    3 folds have theirs).
    """
    cov_every = cov(every) if every.status == "ok" else None
    if cov_every is None:
        return None
    folds = [(r, c) for r in ok if (c := cov(r)) is not None]
    if len(folds) < 3:
        return None
    try:
        return fold_information_statistic(
            np.stack([delta(r) for r, _ in folds]), [c for _, c in folds], cov_every, floor=floor
        )
    except np.linalg.LinAlgError as e:  # the all-views covariance not positive definite
        log.info("the folds' test is not possible (%s)", e)
        return None


def intrinsics_model_covariance(result: RefineResult, names: tuple[Any, ...]) -> tuple[np.ndarray, str]:
    """(model covariance of the free intrinsics ``names``, "full" | "sigmas").

    The marginal of the refinement's joint covariance when it has one for exactly these intrinsics, else
    the diagonal of their model sigmas.
    """
    j = result.cov_x_intrinsics
    if j is not None and tuple(j["intrinsics"]) == tuple(names):
        K = np.asarray(j["intrinsics_kxk"], float)
        try:
            np.linalg.cholesky(0.5 * (K + K.T))
            return 0.5 * (K + K.T), "full"
        except np.linalg.LinAlgError:
            log.warning("the joint intrinsics covariance is not positive definite: validated against the sigmas")
    sig = np.array([result.intrinsics_sigma[k] for k in names], float)
    return np.diag(sig**2), "sigmas"


def _block(
    names: tuple[str, ...],
    cov_model: np.ndarray,
    thetas: np.ndarray,
    *,
    model_form: str = "full",
    test: Union[tuple[float, float], str, None] = None,
) -> Block:
    """One block's validated covariances and its fold test.

    One block's covariances; ``test``: (T, dof) of :func:`fold_information_statistic`, None for the trace
    test of the jackknife against the model (equal leverage), or "none" (no test: the model stands).
    """
    M = np.asarray(cov_model, float)
    if not np.all(np.isfinite(M)):
        raise np.linalg.LinAlgError("the model covariance is not finite")
    V, rho, s = shrunk_jackknife(thetas, M)
    C, lam = generalised_max(M, V)
    if isinstance(test, tuple) and test[1] > 0:
        p, how = chi2_sf(test[0], test[1]), "fold information"
    elif test is None:
        p, how = trace_p_value(s, thetas.shape[0], M.shape[0]), "trace"
    else:
        p, how = float("nan"), "none"
    finding = bool(np.isfinite(p) and p < float(settings()["alpha"]))
    spread = generalised_max(M, jackknife_covariance(thetas))[1]
    return Block(names, M, V, C if finding else 0.5 * (M + M.T), lam, rho, s, p, finding, how, model_form, spread)
