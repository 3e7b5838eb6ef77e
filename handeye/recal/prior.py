"""An earlier result as the prior of a new calibration (``handeye calibrate SESSION --prior RESULT``).

The earlier ``X0`` (covariance ``S0``, the one its verdict uses) enters the refinement as a Gaussian
prior through :class:`handeye.refine.options.Prior`, and so do the earlier intrinsics with their sigmas
(the session starts from them; those without a sigma are held), unless the session brings its own:
one recipe with ``handeye verify``, :func:`handeye.recal.loaded.installed_prior`. A few new views then
update the calibration instead of replacing it.

Whether the data contradict the prior: the update ``u = L^-1 Log(X0^-1 X_post)`` (``S0 = L L^T``) has
covariance ``M = I - L^-1 S_post L^-T`` when the prior is right (a linear Gaussian update), so
``T = sum_k (v_k . u)^2 / m_k`` over the eigenpairs ``(m_k, v_k)`` of ``M`` with ``m_k >= min_variance_share``
is chi-square with that many degrees of freedom (the score test of ``X = X0``; the same statistic as
``handeye verify``'s Wald test in the linear model). When ``p < alpha`` (or the solve with the prior
fails), the prior is not used silently: the session is calibrated again without the prior on X (a vague
term, :data:`handeye.recal.loaded.VAGUE_COV_X`: the data say its mean is wrong, and no inflation of
``S0`` fitted to one drift would be better founded) but with the intrinsics prior (a bump moves the
camera, not its lens), and the result says so, with the drift (the new estimate against ``X0``,
:mod:`handeye.recal.compare`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Optional

import numpy as np
from scipy import stats

from ..errors import InputError
from ..output import plain
from .compare import x_difference
from .loaded import VAGUE_COV_X, LoadedResult, ResultLike, installed_prior, load_result
from .verify import VerifyOptions, change_in_result_frame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class UpdateTest:
    statistic: float
    dof: int
    p_value: float
    update_xi: np.ndarray  # (6,) Log(X0^-1 X_post), rad and m


def update_test(*, cov_prior: np.ndarray, update_xi: np.ndarray, cov_post: np.ndarray,
                min_variance_share: float = 1e-3) -> UpdateTest:
    """The score test of a Gaussian prior ``N(X0, cov_prior)`` against the update the data made to it
    (see the module docstring). ``update_xi`` (6,) in ``X0``'s right tangent; ``cov_post`` (6,6)."""
    L = np.linalg.cholesky(0.5 * (cov_prior + cov_prior.T))
    Li = np.linalg.inv(L)
    u = Li @ np.asarray(update_xi, float)
    M = np.eye(6) - Li @ (0.5 * (cov_post + cov_post.T)) @ Li.T
    m, V = np.linalg.eigh(0.5 * (M + M.T))
    keep = m >= float(min_variance_share)
    proj = V.T @ u
    T = float(np.sum(proj[keep] ** 2 / m[keep]))
    dof = int(keep.sum())
    return UpdateTest(statistic=T, dof=dof, p_value=float(stats.chi2.sf(T, dof)) if dof else 1.0,
                      update_xi=np.asarray(update_xi, float))


def check_prior_fits(installed: LoadedResult, session) -> None:
    """The earlier result must describe this rig: same mode, board; else a one-line InputError."""
    if not installed.ok or installed.cov_x is None:
        raise InputError("the prior result has no hand-eye matrix with a covariance", path=installed.source,
                         hint="use a result calibrated with the refinement (status ok)")
    if session.mode != installed.mode:
        raise InputError(f"the prior is {installed.mode} but the session is {session.mode}", path=installed.source,
                         code="not_comparable", hint="use a result of this rig's mounting mode as --prior")
    if installed.target is not None and session.target.to_dict() != installed.target:
        raise InputError(f"the prior used another board than the session ({session.target.describe()})",
                         path=installed.source, code="not_comparable", hint="use a result of this board as --prior")


def _with_prior(session, options, installed: LoadedResult, *, cov_x=None):
    """(session, options) with the earlier X (covariance ``cov_x``, default its own) and, unless the session
    has its own intrinsics, the earlier intrinsics as priors (:func:`handeye.recal.loaded.installed_prior`:
    the session starts from them, the refinement estimates them under their prior)."""
    own = session.intrinsics is not None and session.intrinsics_prior in ("fixed", "prior")
    prior, held = installed_prior(installed, session_intrinsics=own, cov_x=cov_x)
    ro = dict(options.refine_options, prior=prior)
    if prior.intrinsics is not None:
        ro["intrinsics"] = "estimate"  # the prior's intrinsics term, and no factory prior on top of it
        ro["fix"] = tuple(sorted(set(ro.get("fix", ())) | set(held)))
        session = replace(session, intrinsics=installed.intrinsics, intrinsics_prior="prior")
    return session, replace(options, refine_options=ro)


def calibrate_with_prior(session, options, prior: ResultLike, *, progress=None,
                         verify_options: Optional[VerifyOptions] = None) -> tuple:
    """Calibrate ``session`` (loaded) with the result ``prior`` as the prior of X and the intrinsics;
    when the data contradict it, calibrate again without the prior on X and say so.

    Returns (the CalibrationRun kept, result.json's ``prior`` block: the prior, the update, the test,
    ``contradicted``, ``used`` and, when contradicted, the ``drift``)."""
    from ..pipeline import run_calibration

    progress = progress or (lambda s: None)
    if not options.refine:
        raise InputError("--prior enters the joint refinement", expected="a calibration with the refinement",
                         received="--no-refine", hint="drop --no-refine or --prior")
    o = verify_options or VerifyOptions.from_config()
    installed = prior if isinstance(prior, LoadedResult) else load_result(prior)
    check_prior_fits(installed, session)
    s_p, opts_p = _with_prior(session, options, installed)
    progress(f"calibrating with the prior {installed.source}")
    run = run_calibration(s_p, opts_p, progress=progress)
    rec = {"source": installed.source, "covariance_used": installed.cov_source, "frame": installed.x_name,
           installed.x_name: installed.T_x, "cov_x_6x6": installed.cov_x,
           "sigma_trans_mm": 1000.0 * np.sqrt(np.diag(installed.T_x[:3, :3] @ installed.cov_x[3:, 3:]
                                                      @ installed.T_x[:3, :3].T)),
           "sigma_rot_deg": np.degrees(np.sqrt(np.diag(installed.cov_x[:3, :3]))),
           "intrinsics": "the session's own" if opts_p.refine_options["prior"].intrinsics is None
           else "the prior's, with its sigmas", "alpha": o.alpha}
    contradicted, why = False, ""
    if run.status == "ok" and run.refined is not None:
        t = update_test(cov_prior=installed.cov_x, update_xi=_log_update(installed.T_x, run.T_x),
                        cov_post=run.refined.cov_x_6x6, min_variance_share=o.min_variance_share)
        spread = installed.cov_x - run.refined.cov_x_6x6  # the update's covariance when the prior is right
        upd = change_in_result_frame(installed.T_x, t.update_xi, 0.5 * (spread + spread.T))
        rec["update"] = dict(upd, sigma_meaning="1-sigma of the update when the prior is right (prior minus "
                                                "posterior covariance)")
        rec["test"] = {"kind": "score test of X = X_prior: the update against its spread when the prior is right",
                       "statistic": t.statistic, "dof": t.dof, "p_value": t.p_value}
        contradicted = t.p_value < o.alpha
        why = f"the update is beyond the prior's uncertainty (p = {t.p_value:.3g} < {o.alpha:g})"
    else:
        contradicted = True
        why = f"the calibration with the prior failed ({run.error})"
    rec["contradicted"] = contradicted
    if not contradicted:
        rec["used"] = "prior"
        rec["summary"] = (f"the prior {installed.x_name} was updated by {rec['update']['trans_mm']:.2f} mm, "
                          f"{rec['update']['rot_deg']:.3f} deg; the data agree with it "
                          f"(p = {rec['test']['p_value']:.3g})")
        log.info("prior: %s", rec["summary"])
        return _described(run), plain(rec, nan_to_none=True)
    progress("the data contradict the prior: calibrating without it")
    s_n, opts_n = _with_prior(session, options, installed, cov_x=VAGUE_COV_X)  # the intrinsics prior stays
    run_n = run_calibration(s_n, opts_n, progress=progress)
    rec["used"] = "no prior on X (the new views alone; the prior's intrinsics kept)"
    if run_n.status == "ok" and run_n.refined is not None:
        d = x_difference(installed.T_x, installed.cov_x, run_n.T_x, run_n.refined.cov_x_6x6)
        p = float(stats.chi2.sf(d["d2"], 6))
        rec["drift"] = {"d_trans_mm": d["d_trans_mm"], "d_rot_deg": d["d_rot_deg"],
                        "trans_mm": float(np.linalg.norm(d["d_trans_mm"])),
                        "rot_deg": float(np.linalg.norm(d["d_rot_deg"])), "sigma_trans_mm": d["sigma_trans_mm"],
                        "sigma_rot_deg": d["sigma_rot_deg"], "mahalanobis2": d["d2"], "p_value": p}
        rec["summary"] = (f"the data contradict the prior: {why}; {installed.x_name} drifted by "
                          f"{rec['drift']['trans_mm']:.2f} mm, {rec['drift']['rot_deg']:.3f} deg "
                          "(the result is the new views' calibration without the prior on X)")
    else:
        rec["summary"] = f"the data contradict the prior: {why}; the calibration without it failed too"
    log.info("prior: %s", rec["summary"])
    return _described(run_n), plain(rec, nan_to_none=True)


def _log_update(T_x0: np.ndarray, T_x: np.ndarray) -> np.ndarray:
    from ..frames import tangent_difference

    return tangent_difference(T_x0, T_x)


def _described(run):
    """The run with the prior in its options described in words (result.json's provenance records the
    options; the prior's numbers are in the ``prior`` block)."""
    ro = dict(run.options.refine_options)
    if "prior" in ro:
        ro["prior"] = "the earlier result in the prior block"
    return replace(run, options=replace(run.options, refine_options=ro))
