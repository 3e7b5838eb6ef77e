"""The difference between two calibrations of one rig, and whether it exceeds their uncertainty.

``xi = Log(inv(X_a) · X_b)`` (handeye's one tangent: rotation first, along the camera axes of ``X_a``)
is tested against ``S = S_a + Ad · S_b · Ad^T`` (``Ad`` the adjoint of ``inv(X_a) · X_b``, which moves
``X_b``'s right-tangent covariance into ``X_a``'s): ``d2 = xi^T S^-1 xi`` is chi-square with 6 degrees
of freedom when both results calibrate the same unchanged rig with independent data, so
``p = P(chi2_6 > d2)``; ``drifted`` when ``p < alpha``.

The intrinsics are tested the same way: with both results' joint covariances of X and the free
intrinsics (``refinement.cov_x_intrinsics``, the same free intrinsics in both), over those intrinsics with
the sum of their covariances, chi-square with as many degrees of freedom; otherwise over fx, fy, cx, cy
with the sum of their variances (a diagonal test). When that test finds the intrinsics the same, the two
results share one camera, and X is tested given it: each result's X error is largely its intrinsics'
error (a principal point error tilts X), so the part of ``xi`` the intrinsics difference ``dk`` explains is
taken out, ``xi_c = xi - C K^-1 dk`` with ``C = C_a + Ad C_b`` and ``K = K_a + K_b``, tested against
``S_c = S - C K^-1 C^T`` (chi-square with 6 degrees of freedom: ``xi_c`` is independent of ``dk``, so the
choice made on ``dk`` leaves its distribution as it is). When the intrinsics changed, or a result lacks the
joint covariance, X is tested alone as above; ``x_test`` says which test was made.

Two results are comparable only when they describe the same quantity: the same mounting mode (and so
the same frame of X), the same target and the same image size. Otherwise :func:`compare_results`
returns ``comparable=False`` with ``reason`` naming the difference.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..config import load_preset
from ..frames import inv_T, rotvec_from_R, se3_adjoint, tangent_difference
from ..output import plain
from .loaded import LoadedResult, ResultLike, load_result

#: the test's level (configs/recal.yaml test.alpha): an unchanged rig is called drifted this often
ALPHA = float(load_preset("recal")["test"]["alpha"])
INTRINSICS_COMPARED = ("fx", "fy", "cx", "cy")
X_ALONE = "X alone: the sum of the two covariances of X"
X_GIVEN_INTRINSICS = ("X given the shared camera: the part of the difference the intrinsics difference explains "
                      "taken out (their joint covariances; the intrinsics test found them the same)")


@dataclass(frozen=True)
class Comparison:
    """``X_b`` against ``X_a``. Translations: ``t_b - t_a`` along the parent frame's axes (mm);
    rotations: ``rotvec(R_a^T R_b)`` about the camera axes of ``X_a`` (deg); ``xi``: the tangent
    difference the test uses; ``intrinsics``: per name ``{a, b, diff, sigma, z}`` and ``mahalanobis2``,
    ``dof``, ``p_value``, ``drifted`` (absent when neither result has intrinsics sigmas)."""

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
    x_test: str = X_ALONE  # which test of X was made (module docstring)

    def to_dict(self) -> dict:
        return plain({
            "comparable": self.comparable, "reason": self.reason, "frame": self.frame,
            "d_trans_mm": self.d_trans_mm, "d_rot_deg": self.d_rot_deg, "trans_mm": self.trans_mm,
            "rot_deg": self.rot_deg, "sigma_trans_mm": self.sigma_trans_mm, "sigma_rot_deg": self.sigma_rot_deg,
            "mahalanobis2": self.mahalanobis2, "dof": 6, "p_value": self.p_value, "alpha": self.alpha,
            "drifted": self.drifted, "intrinsics": self.intrinsics, "xi_rad_m": self.xi,
            "xi_definition": "Log(inv(X_a) X_b): rotation (rad) then translation (m), along the camera axes of X_a",
            "d_trans_definition": "t_b - t_a along the parent frame's axes (mm)",
            "d_rot_definition": "rotation vector of R_a^T R_b about the camera axes of X_a (deg)",
            "results": list(self.sources), "covariances": list(self.cov_sources), "note": self.note,
            "x_test": self.x_test},
            nan_to_none=True)


def not_comparable(reason: str, frame: str = "", *, alpha: float = ALPHA, sources: tuple = ()) -> Comparison:
    nan3 = np.full(3, np.nan)
    return Comparison(comparable=False, reason=reason, frame=frame, d_trans_mm=nan3, d_rot_deg=nan3,
                      trans_mm=float("nan"), rot_deg=float("nan"), mahalanobis2=float("nan"),
                      p_value=float("nan"), drifted=False, alpha=alpha, sources=sources)


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
        return f"boards differ: A used {_target_text(a.target)}, B used {_target_text(b.target)}"
    if a.image_size and b.image_size and a.image_size != b.image_size:
        return (f"camera resolutions differ: A is {a.image_size[0]}x{a.image_size[1]}, "
                f"B is {b.image_size[0]}x{b.image_size[1]}")
    for r, name in ((a, "A"), (b, "B")):
        if r.cov_x is None:
            return f"result {name} has no covariance of {r.x_name} (calibrated without the refinement)"
    return ""


def _target_text(t) -> str:
    if not isinstance(t, dict):
        return "an unknown board"
    return " ".join(f"{k}={v}" for k, v in t.items() if k in ("type", "inner_corners", "squares", "grid", "square_m",
                                                               "marker_m", "spacing_m", "dictionary")) or str(t)[:60]


def x_difference(T_a: np.ndarray, cov_a: np.ndarray, T_b: np.ndarray, cov_b: np.ndarray) -> dict:
    """The tangent difference ``xi`` (6,), its covariance ``S`` (6,6) (``cov_b`` moved into ``T_a``'s
    tangent), ``d2 = xi^T S^-1 xi`` and the derived per-axis forms (see the module docstring)."""
    xi = tangent_difference(T_a, T_b)
    Ad = se3_adjoint(inv_T(T_a) @ T_b)
    S = np.asarray(cov_a, float) + Ad @ np.asarray(cov_b, float) @ Ad.T
    S = 0.5 * (S + S.T)
    d2 = float(xi @ np.linalg.solve(S, xi))
    R_a = T_a[:3, :3]
    # translation t_b - t_a = R_a · (J v) ~ R_a v to first order: its covariance R_a S_vv R_a^T
    cov_t = R_a @ S[3:, 3:] @ R_a.T
    return {"xi": xi, "S": S, "d2": d2,
            "d_trans_mm": 1000.0 * (T_b[:3, 3] - T_a[:3, 3]),
            "d_rot_deg": np.degrees(rotvec_from_R(R_a.T @ T_b[:3, :3])),
            "sigma_trans_mm": 1000.0 * np.sqrt(np.diag(cov_t)),
            "sigma_rot_deg": np.degrees(np.sqrt(np.diag(S[:3, :3])))}


def shared_intrinsics(a: LoadedResult, b: LoadedResult) -> tuple | None:
    """(names, dk = K_b - K_a (k,), C_a (6,k), C_b (6,k), K_a + K_b (k,k)) from the two joint covariances of X
    and the free intrinsics, when both have one over the same intrinsics; else None."""
    ja, jb = a.cov_x_intrinsics, b.cov_x_intrinsics
    if ja is None or jb is None or tuple(ja[0]) != tuple(jb[0]) or a.intrinsics is None or b.intrinsics is None:
        return None
    from ..camera import INTRINSIC_NAMES

    idx = [INTRINSIC_NAMES.index(n) for n in ja[0]]
    dk = b.intrinsics.as_vector()[idx] - a.intrinsics.as_vector()[idx]
    return tuple(ja[0]), dk, ja[1], jb[1], ja[2] + jb[2]


def intrinsics_difference(a: LoadedResult, b: LoadedResult, *, alpha: float = ALPHA) -> dict:
    """Per intrinsic (fx, fy, cx, cy) ``{a, b, diff, sigma, z}`` and the chi-square test of the intrinsics
    (module docstring: over the free intrinsics with their joint covariance, else diagonal over fx, fy, cx,
    cy); {} when either result has no intrinsics."""
    if a.intrinsics is None or b.intrinsics is None:
        return {}
    shared = shared_intrinsics(a, b)
    out, d2, dof = {}, 0.0, 0
    for name in INTRINSICS_COMPARED:
        va, vb = float(getattr(a.intrinsics, name)), float(getattr(b.intrinsics, name))
        var = a.intrinsics_sigma.get(name, 0.0) ** 2 + b.intrinsics_sigma.get(name, 0.0) ** 2
        if shared is not None and name in shared[0]:
            var = float(shared[4][shared[0].index(name), shared[0].index(name)])
        sd = float(np.sqrt(var))
        z = (vb - va) / sd if sd > 0 else float("nan")
        out[name] = {"a": va, "b": vb, "diff": vb - va, "sigma": sd, "z": z}
        if sd > 0:
            d2 += z * z
            dof += 1
    test = "diagonal over fx, fy, cx, cy: a result without the joint covariance of X and the intrinsics"
    if shared is not None:
        names, dk, _, _, K = shared
        try:
            d2, dof = float(dk @ np.linalg.solve(K, dk)), len(names)
            test = f"over the free intrinsics ({', '.join(names)}) with their joint covariances"
        except np.linalg.LinAlgError:
            pass
    if dof:
        p = float(stats.chi2.sf(d2, dof))
        out.update(mahalanobis2=d2, dof=dof, p_value=p, drifted=bool(p < alpha), test=test)
    return out


def x_given_intrinsics(d: dict, a: LoadedResult, b: LoadedResult, intr: dict) -> dict | None:
    """``d`` (:func:`x_difference`) with ``d2`` of X given the shared camera (module docstring), or None when
    the intrinsics were not tested with the joint covariances or were found changed."""
    shared = shared_intrinsics(a, b)
    if shared is None or intr.get("drifted", True) or not str(intr.get("test", "")).startswith("over the free"):
        return None
    _, dk, C_a, C_b, K = shared
    Ad = se3_adjoint(inv_T(a.T_x) @ b.T_x)
    C = C_a + Ad @ C_b
    try:
        xi_c = d["xi"] - C @ np.linalg.solve(K, dk)
        S_c = d["S"] - C @ np.linalg.solve(K, C.T)
        S_c = 0.5 * (S_c + S_c.T)
        np.linalg.cholesky(S_c)
        return dict(d, d2=float(xi_c @ np.linalg.solve(S_c, xi_c)))
    except np.linalg.LinAlgError:
        return None


def compare_loaded(a: LoadedResult, b: LoadedResult, *, alpha: float = ALPHA) -> Comparison:
    """:func:`compare_results` of two loaded results."""
    sources = (a.source, b.source)
    reason = why_not_comparable(a, b)
    if reason:
        return not_comparable(reason, a.x_name if a.x_name == b.x_name else "", alpha=alpha, sources=sources)
    d = x_difference(a.T_x, a.cov_x, b.T_x, b.cov_x)
    intr = intrinsics_difference(a, b, alpha=alpha)
    given = x_given_intrinsics(d, a, b, intr)
    x_test = X_ALONE if given is None else X_GIVEN_INTRINSICS
    d = d if given is None else given
    p = float(stats.chi2.sf(d["d2"], 6))
    return Comparison(comparable=True, reason="", frame=a.x_name, d_trans_mm=d["d_trans_mm"],
                      d_rot_deg=d["d_rot_deg"], trans_mm=float(np.linalg.norm(d["d_trans_mm"])),
                      rot_deg=float(np.linalg.norm(d["d_rot_deg"])), mahalanobis2=d["d2"], p_value=p,
                      drifted=bool(p < alpha), intrinsics=intr, alpha=alpha,
                      xi=d["xi"], sigma_trans_mm=d["sigma_trans_mm"], sigma_rot_deg=d["sigma_rot_deg"],
                      sources=sources, cov_sources=(a.cov_source, b.cov_source), note=_dependence_note(a, b),
                      x_test=x_test)


def _dependence_note(a: LoadedResult, b: LoadedResult) -> str:
    """A warning when a result was calibrated with an earlier one as its prior (the two are then not
    independent, and the test's p-value is too large)."""
    for r, name in ((a, "A"), (b, "B")):
        prior = r.raw.get("prior") or {}
        if prior.get("used") == "prior":
            return (f"result {name} was calibrated with {prior.get('source')} as its prior: the two are not "
                    "independent and the p-value is too large")
    return ""


def compare_results(a: ResultLike, b: ResultLike, *, alpha: float = ALPHA) -> Comparison:
    """Compare result ``b`` with result ``a`` (each a result folder, a result.json path or the loaded
    dict). Unreadable files raise :class:`~handeye.errors.InputError`; results that do not describe one
    quantity give ``comparable=False`` and the ``reason``."""
    return compare_loaded(load_result(a), load_result(b), alpha=alpha)


def comparison_lines(c: Comparison) -> list[str]:
    """A short table of a comparison for a terminal."""
    if not c.comparable:
        return [f"not comparable: {c.reason}"]
    ax = "xyz"
    lines = [f"{c.frame}: B - A", f"  {'axis':<6}{'d [mm]':>10}{'sigma':>9}   {'d [deg]':>10}{'sigma':>9}"]
    for k in range(3):
        lines.append(f"  {ax[k]:<6}{c.d_trans_mm[k]:>10.3f}{c.sigma_trans_mm[k]:>9.3f}   "
                     f"{c.d_rot_deg[k]:>10.4f}{c.sigma_rot_deg[k]:>9.4f}")
    lines.append(f"  {'norm':<6}{c.trans_mm:>10.3f}{'':>9}   {c.rot_deg:>10.4f}")
    lines.append(f"  Mahalanobis^2 {c.mahalanobis2:.2f} (6 dof), p = {c.p_value:.3g}: "
                 + ("DRIFTED" if c.drifted else "same within the uncertainty") + f" at {c.alpha:g}")
    lines.append(f"  test: {c.x_test}")
    if c.note:
        lines.append(f"  note: {c.note}")
    it = c.intrinsics
    if it:
        lines.append("intrinsics: " + ", ".join(
            f"{n} {it[n]['diff']:+.2f} px" + (f" (z {it[n]['z']:+.1f})" if np.isfinite(it[n]['z']) else "")
            for n in INTRINSICS_COMPARED if n in it))
        if "p_value" in it:
            lines.append(f"  Mahalanobis^2 {it['mahalanobis2']:.2f} ({it['dof']} dof), p = {it['p_value']:.3g}: "
                         + ("CHANGED" if it["drifted"] else "same within the uncertainty"))
    return lines
