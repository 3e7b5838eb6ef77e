"""The difference between two calibrations of one rig, and whether it exceeds their uncertainty.

``xi = Log(inv(X_a) · X_b)`` is tested against the sum of the two covariances: chi-square with 6
degrees of freedom, or F when the results estimated their robot noise. When both carry the joint
covariance of X and the intrinsics, the test is of X given the intrinsics difference (a moved camera
stands out from a lens re-estimate), with the test of X alone beside it; the intrinsics get their own
test. Results of different modes, targets or image sizes are not comparable (``reason`` says why).

See docs/recalibrate.md for the derivation and the forms rejected.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np
from scipy import stats

from ..camera import INTRINSIC_NAMES
from ..config import load_preset
from ..frames import inv_T, rotvec_from_R, se3_adjoint, tangent_difference
from ..output import plain
from ..session.target_spec import target_words
from ..stats import satterthwaite_dof, wald_p_value
from .loaded import LoadedResult, ResultLike, axes_words, load_result

#: the test's level (configs/recal.yaml test.alpha): an unchanged rig is called drifted this often
ALPHA = float(load_preset("recal")["test"]["alpha"])
INTRINSICS_COMPARED = ("fx", "fy", "cx", "cy")


@dataclass(frozen=True)
class Comparison:
    """The difference of ``X_b`` against ``X_a`` and its test.

    ``X_b`` against ``X_a``. Translations: ``t_b - t_a`` along the parent frame's axes (mm);
    rotations: ``rotvec(R_a^T R_b)`` about the camera axes of ``X_a`` (deg); ``xi``: the tangent
    difference the test uses; ``intrinsics``: per name ``{a, b, diff, sigma, z}`` and ``mahalanobis2``,
    ``dof``, ``p_value``, ``drifted`` (absent when neither result has intrinsics sigmas).
    """

    comparable: bool
    reason: str
    frame: str
    d_trans_mm: np.ndarray  # (3,)
    d_rot_deg: np.ndarray  # (3,)
    trans_mm: float
    rot_deg: float
    mahalanobis2: float
    p_value: float
    drifted: bool
    intrinsics: dict = field(default_factory=dict)
    alpha: float = ALPHA
    xi: np.ndarray = field(default_factory=lambda: np.full(6, np.nan))  # (6,) rad, m
    sigma_trans_mm: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))  # (3,) of the difference
    sigma_rot_deg: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))  # (3,) of the difference
    sources: tuple = ()  # the two result paths
    cov_sources: tuple = ()  # which covariance each result contributed
    note: str = ""  # e.g. a result updated from the other with --prior: the test assumes independent results
    test: str = "X alone"  # "X given the intrinsics difference" when both results carry the joint covariance
    mahalanobis2_x_alone: float = float("nan")  # the test of X alone (= mahalanobis2 when that is the test)
    p_value_x_alone: float = float("nan")
    explained_trans_mm: float = float("nan")  # |G dk|: the part of the difference the intrinsics difference explains
    explained_rot_deg: float = float("nan")
    # degrees of freedom of the difference's covariance when the results estimated their robot noise (the p-values
    # then from F(6, nu), :func:`noise_dof`); None: chi-square
    robot_noise_dof: Optional[float] = None

    def to_dict(self) -> dict:
        return plain(
            {
                "comparable": self.comparable,
                "reason": self.reason,
                "frame": self.frame,
                "d_trans_mm": self.d_trans_mm,
                "d_rot_deg": self.d_rot_deg,
                "trans_mm": self.trans_mm,
                "rot_deg": self.rot_deg,
                "sigma_trans_mm": self.sigma_trans_mm,
                "sigma_rot_deg": self.sigma_rot_deg,
                "mahalanobis2": self.mahalanobis2,
                "dof": 6,
                "p_value": self.p_value,
                "alpha": self.alpha,
                "drifted": self.drifted,
                "intrinsics": self.intrinsics,
                "xi_rad_m": self.xi,
                "xi_definition": "Log(inv(X_a) X_b): rotation (rad) then translation (m), along the camera axes of X_a",
                "d_trans_definition": "t_b - t_a along the parent frame's axes (mm)",
                "d_rot_definition": "rotation vector of R_a^T R_b about the camera axes of X_a (deg)",
                "results": list(self.sources),
                "covariances": list(self.cov_sources),
                "note": self.note,
                "test": self.test,
                "mahalanobis2_x_alone": self.mahalanobis2_x_alone,
                "p_value_x_alone": self.p_value_x_alone,
                "explained_by_intrinsics_trans_mm": self.explained_trans_mm,
                "explained_by_intrinsics_rot_deg": self.explained_rot_deg,
                "robot_noise_dof": self.robot_noise_dof,
                "reference": None
                if not self.comparable
                else "chi-square(6)"
                if self.robot_noise_dof is None
                else f"6 × F(6, {self.robot_noise_dof:.0f}) (the robot noise levels estimated)",
            },
            nan_to_none=True,
        )


def not_comparable(reason: str, frame: str = "", *, alpha: float = ALPHA, sources: tuple = ()) -> Comparison:
    nan3 = np.full(3, np.nan)
    return Comparison(
        comparable=False,
        reason=reason,
        frame=frame,
        d_trans_mm=nan3,
        d_rot_deg=nan3,
        trans_mm=float("nan"),
        rot_deg=float("nan"),
        mahalanobis2=float("nan"),
        p_value=float("nan"),
        drifted=False,
        alpha=alpha,
        sources=sources,
    )


def why_not_comparable(a: LoadedResult, b: LoadedResult) -> str:
    """'' when the two results describe one quantity, else one line naming the first difference."""
    for r, name in ((a, "A"), (b, "B")):
        if not r.ok:
            return f"result {name} has no hand-eye matrix (status {r.status})"
    if a.mode != b.mode:
        return f"mounting modes differ: A is {a.mode}, B is {b.mode}"
    if a.x_name != b.x_name:
        return f"frames differ: A gives {a.x_name}, B gives {b.x_name}"
    if a.target != b.target:
        return f"boards differ: A used {target_words(a.target)}, B used {target_words(b.target)}"
    if a.image_size and b.image_size and a.image_size != b.image_size:
        return (
            f"camera resolutions differ: A is {a.image_size[0]}x{a.image_size[1]}, "
            f"B is {b.image_size[0]}x{b.image_size[1]}"
        )
    for r, name in ((a, "A"), (b, "B")):
        if r.cov_x is None:
            return f"result {name} has no covariance of {r.x_name} (calibrated without the refinement)"
    return ""


def x_difference(T_a: np.ndarray, cov_a: np.ndarray, T_b: np.ndarray, cov_b: np.ndarray) -> dict:
    """The tangent difference ``xi`` (6,) of the two transforms, its covariance and derived figures.

    The tangent difference ``xi`` (6,), its covariance ``S`` (6,6) (``cov_b`` moved into ``T_a``'s
    tangent), ``d2 = xi^T S^-1 xi`` and the derived per-axis forms (see the module docstring).
    """
    xi = tangent_difference(T_a, T_b)
    Ad = se3_adjoint(inv_T(T_a) @ T_b)
    S = np.asarray(cov_a, float) + Ad @ np.asarray(cov_b, float) @ Ad.T
    S = 0.5 * (S + S.T)
    d2 = float(xi @ np.linalg.solve(S, xi))
    R_a = T_a[:3, :3]
    # translation t_b - t_a = R_a · (J v) ~ R_a v to first order: its covariance R_a S_vv R_a^T
    cov_t = R_a @ S[3:, 3:] @ R_a.T
    return {
        "xi": xi,
        "S": S,
        "d2": d2,
        "d_trans_mm": 1000.0 * (T_b[:3, 3] - T_a[:3, 3]),
        "d_rot_deg": np.degrees(rotvec_from_R(R_a.T @ T_b[:3, :3])),
        "sigma_trans_mm": 1000.0 * np.sqrt(np.diag(cov_t)),
        "sigma_rot_deg": np.degrees(np.sqrt(np.diag(S[:3, :3]))),
    }


def x_given_intrinsics(a: LoadedResult, b: LoadedResult, d: dict) -> Optional[dict]:
    """The test of X given the intrinsics difference.

    The test of X given the intrinsics difference (see the module docstring) on the difference ``d`` of
    :func:`x_difference`: ``{"d2", "explained" (6,): G dk}``; None when either result lacks the joint
    covariance or their free intrinsics differ.
    """
    ja, jb = a.x_on_intrinsics, b.x_on_intrinsics
    if ja is None or jb is None or tuple(ja[0]) != tuple(jb[0]) or a.intrinsics is None or b.intrinsics is None:
        return None
    idx = [INTRINSIC_NAMES.index(n) for n in ja[0]]
    assert a.T_x is not None and b.T_x is not None, "compared results have X"
    dk = b.intrinsics.as_vector()[idx] - a.intrinsics.as_vector()[idx]
    Ad = se3_adjoint(inv_T(a.T_x) @ b.T_x)
    S_kk = ja[2] + jb[2]
    W = ja[3] + Ad @ jb[3]
    try:
        G = np.linalg.solve(S_kk, (ja[1] + Ad @ jb[1]).T).T
        V = d["S"] - W @ np.linalg.solve(S_kk, W.T)
        V = 0.5 * (V + V.T)
        r = d["xi"] - G @ dk
        d2 = float(r @ np.linalg.solve(V, r))
    except np.linalg.LinAlgError:
        return None
    if not np.isfinite(d2) or np.linalg.eigvalsh(V).min() <= 0.0:
        return None
    return {"d2": d2, "explained": G @ dk}


def intrinsics_difference(a: LoadedResult, b: LoadedResult, *, alpha: float = ALPHA) -> dict:
    """Per intrinsic (fx, fy, cx, cy) the difference and its z, with the diagonal chi-square test.

    Per intrinsic (fx, fy, cx, cy) ``{a, b, diff, sigma, z}`` and the diagonal chi-square test over
    those with a sigma; {} when either result has no intrinsics.
    """
    if a.intrinsics is None or b.intrinsics is None:
        return {}
    full = _intrinsics_joint_test(a, b, alpha)
    out: dict[str, Any] = {}
    d2, dof = 0.0, 0
    for name in INTRINSICS_COMPARED:
        va, vb = float(getattr(a.intrinsics, name)), float(getattr(b.intrinsics, name))
        var = a.intrinsics_sigma.get(name, 0.0) ** 2 + b.intrinsics_sigma.get(name, 0.0) ** 2
        sd = float(np.sqrt(var))
        z = (vb - va) / sd if sd > 0 else float("nan")
        out[name] = {"a": va, "b": vb, "diff": vb - va, "sigma": sd, "z": z}
        if sd > 0:
            d2 += z * z
            dof += 1
    if full is not None:
        out.update(full)
    elif dof:
        p = float(stats.chi2.sf(d2, dof))
        out.update(
            mahalanobis2=d2,
            dof=dof,
            p_value=p,
            drifted=bool(p < alpha),
            test="diagonal: the results store the intrinsics' sigmas, not their correlations",
        )
    return out


def _intrinsics_joint_test(a: LoadedResult, b: LoadedResult, alpha: float) -> Optional[dict]:
    """The test of (fx, fy, cx, cy) under the sum of the two results' full covariances of them.

    The test of (fx, fy, cx, cy) under the sum of the two results' full covariances of them (the joint
    covariance carried to the verdict: fx and fy move together), when both carry it for all four.
    """
    ja, jb = a.cov_x_intrinsics, b.cov_x_intrinsics
    if (
        ja is None
        or jb is None
        or not set(INTRINSICS_COMPARED) <= set(ja[0])
        or not set(INTRINSICS_COMPARED) <= set(jb[0])
    ):
        return None
    ia, ib = ([list(j[0]).index(n) for n in INTRINSICS_COMPARED] for j in (ja, jb))
    S = ja[2][np.ix_(ia, ia)] + jb[2][np.ix_(ib, ib)]
    dk = np.array([float(getattr(b.intrinsics, n) - getattr(a.intrinsics, n)) for n in INTRINSICS_COMPARED])
    try:
        d2 = float(dk @ np.linalg.solve(0.5 * (S + S.T), dk))
    except np.linalg.LinAlgError:
        return None
    p = float(stats.chi2.sf(d2, len(dk)))
    return dict(
        mahalanobis2=d2,
        dof=len(dk),
        p_value=p,
        drifted=bool(p < alpha),
        test="full covariance of fx, fy, cx, cy (with their correlations)",
    )


def compare_loaded(a: LoadedResult, b: LoadedResult, *, alpha: float = ALPHA) -> Comparison:
    """:func:`compare_results` of two loaded results."""
    sources = (a.label, b.label)
    reason = why_not_comparable(a, b)
    if reason:
        return not_comparable(reason, a.x_name if a.x_name == b.x_name else "", alpha=alpha, sources=sources)
    assert a.T_x is not None and b.T_x is not None, "comparable results have X (why_not_comparable)"
    assert a.cov_x is not None and b.cov_x is not None, "comparable results have its covariance"
    d = x_difference(a.T_x, a.cov_x, b.T_x, b.cov_x)
    nu = noise_dof(a, d["S"], b)
    p_alone = wald_p_value(d["d2"], 6, nu)
    g = x_given_intrinsics(a, b, d)
    extra = {"test": "X alone", "mahalanobis2_x_alone": d["d2"], "p_value_x_alone": p_alone}
    d2, p = d["d2"], p_alone
    if g is not None:
        d2 = g["d2"]
        p = wald_p_value(d2, 6, nu)
        e = g["explained"]
        extra.update(
            test="X given the intrinsics difference",
            explained_trans_mm=float(1000.0 * np.linalg.norm(a.T_x[:3, :3] @ e[3:])),
            explained_rot_deg=float(np.degrees(np.linalg.norm(e[:3]))),
        )
    return Comparison(
        comparable=True,
        reason="",
        frame=a.x_name,
        d_trans_mm=d["d_trans_mm"],
        d_rot_deg=d["d_rot_deg"],
        trans_mm=float(np.linalg.norm(d["d_trans_mm"])),
        rot_deg=float(np.linalg.norm(d["d_rot_deg"])),
        mahalanobis2=d2,
        p_value=p,
        drifted=bool(p < alpha),
        intrinsics=intrinsics_difference(a, b, alpha=alpha),
        alpha=alpha,
        xi=d["xi"],
        sigma_trans_mm=d["sigma_trans_mm"],
        sigma_rot_deg=d["sigma_rot_deg"],
        sources=sources,
        cov_sources=(a.cov_source, b.cov_source),
        note=_dependence_note(a, b),
        robot_noise_dof=nu,
        **extra,
    )


def noise_dof(a: LoadedResult, S: np.ndarray, b: LoadedResult) -> Optional[float]:
    """Degrees of freedom of the difference's covariance when the robot noise was estimated.

    Degrees of freedom of the covariance ``S = S_a + Ad S_b Ad^T`` of the difference when the results
    estimated their robot noise (:attr:`~handeye.recal.loaded.LoadedResult.robot_noise_dof`): Satterthwaite's,
    each result's share of ``S`` its average over the six whitened directions; None when neither did, or when
    their covariances carry those degrees of freedom already (``refinement.cov_x_dof_factor``).
    """
    # a result whose covariance carries its noise levels' degrees of freedom already is read as known
    nu_a, nu_b = (None if r.cov_x_carries_noise_dof else r.robot_noise_dof for r in (a, b))
    if nu_a is None and nu_b is None:
        return None
    # the shares of the unconditional covariance S serve the conditional test too (X given the intrinsics
    # difference): each result's noise level scales its part of both alike
    assert a.cov_x is not None, "compared results have the covariance of X"
    share_a = float(np.clip(np.trace(np.linalg.solve(S, a.cov_x)) / 6.0, 0.0, 1.0))
    return satterthwaite_dof((share_a, 1.0 - share_a), (nu_a, nu_b))


def _dependence_note(a: LoadedResult, b: LoadedResult) -> str:
    """A warning when a result was calibrated with an earlier one as its prior.

    A warning when a result was calibrated with an earlier one as its prior (the two are then not
    independent, and the test's p-value is too large), or, after a contradicted prior, with the earlier
    intrinsics (and board pose) as priors; the stronger tie first.
    """
    blocks = [(name, r.raw.get("prior") or {}) for r, name in ((a, "A"), (b, "B"))]
    for name, prior in blocks:
        if prior.get("used") == "prior":
            return (
                f"result {name} was calibrated with {prior.get('source')} as its prior: the two are not "
                "independent and the p-value is too large"
            )
    for name, prior in blocks:  # a contradicted prior: what of the earlier result stayed a prior
        kept = [
            w
            for w, yes in (
                ("intrinsics", str(prior.get("intrinsics", "")).startswith("the prior's")),
                ("board pose", bool(prior.get("board_prior"))),
            )
            if yes
        ]
        if prior.get("source") and kept:
            return (
                f"result {name} was calibrated with the {' and '.join(kept)} of {prior.get('source')} as priors: "
                "the two are not independent"
            )
    return ""


def compare_results(
    a: ResultLike,
    b: ResultLike,
    *,
    alpha: float = ALPHA,
    camera_a: Optional[str] = None,
    camera_b: Optional[str] = None,
) -> Comparison:
    """Compare result ``b`` with result ``a``.

    Compare result ``b`` with result ``a`` (each a result folder, a result.json path or the loaded
    dict; a cell: its camera ``camera_a`` / ``camera_b``). Unreadable files raise
    :class:`~handeye.errors.InputError`; results that do not describe one quantity give ``comparable=False``
    and the ``reason``.
    """
    return compare_loaded(load_result(a, camera=camera_a), load_result(b, camera=camera_b), alpha=alpha)


def comparison_lines(c: Comparison) -> list[str]:
    """A short table of a comparison for a terminal."""
    if not c.comparable:
        return [f"not comparable: {c.reason}"]
    ax = "xyz"
    lines = [
        f"{c.frame}: B - A ({axes_words(c.frame)})",
        f"  {'axis':<6}{'d [mm]':>10}{'sigma':>9}   {'d [deg]':>10}{'sigma':>9}",
    ]
    for k in range(3):
        lines.append(
            f"  {ax[k]:<6}{c.d_trans_mm[k]:>10.3f}{c.sigma_trans_mm[k]:>9.3f}   "
            f"{c.d_rot_deg[k]:>10.4f}{c.sigma_rot_deg[k]:>9.4f}"
        )
    lines.append(f"  {'norm':<6}{c.trans_mm:>10.3f}{'':>9}   {c.rot_deg:>10.4f}")
    if c.test != "X alone":
        lines.append(
            f"  the intrinsics difference explains {c.explained_trans_mm:.3f} mm, {c.explained_rot_deg:.4f} deg "
            f"of it (X alone: Mahalanobis^2 {c.mahalanobis2_x_alone:.2f}, p = {c.p_value_x_alone:.3g})"
        )
    lines.append(
        f"  {c.test}: Mahalanobis^2 {c.mahalanobis2:.2f} (6 dof), p = {c.p_value:.3g}: "
        + ("DRIFTED" if c.drifted else "same within the uncertainty")
        + f" at {c.alpha:g}"
    )
    if c.note:
        lines.append(f"  note: {c.note}")
    it = c.intrinsics
    if it:
        lines.append(
            "intrinsics: "
            + ", ".join(
                f"{n} {it[n]['diff']:+.2f} px" + (f" (z {it[n]['z']:+.1f})" if np.isfinite(it[n]["z"]) else "")
                for n in INTRINSICS_COMPARED
                if n in it
            )
        )
        if "p_value" in it:
            lines.append(
                f"  Mahalanobis^2 {it['mahalanobis2']:.2f} ({it['dof']} dof), p = {it['p_value']:.3g}: "
                + ("CHANGED (the exit code follows the test of X)" if it["drifted"] else "same within the uncertainty")
            )
    return lines
