"""Everything the templates show, computed from a result folder (plain values, no HTML here).

Every key of result.json is optional except ``status`` and ``mode``: partial results (failed runs,
``--no-refine``, results written before the refinement or diagnostics existed) still build. Each
section's builder lives in :mod:`handeye.report.sections`; this module assembles and judges them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..mounting import EYE_IN_HAND, MODES, mounting
from ..session.target_spec import is_tracked
from .advice import failure_advice, root_cause, untrusted_metrics
from .folder import ResultFolder
from .formatting import num
from .metrics import qa_metrics
from .observations import as_cov6, as_T, finite, median_board_distance_m, view_fits
from .qa import evaluate
from .sections.diagnostics import _cross_validation, _findings, _stages
from .sections.methods import _methods, _offsets, methods_views
from .sections.models import _intrinsics_rows, _noise, _robot_model, _tracker
from .sections.provenance import _meta, _provenance
from .sections.result import _prior_block, _result_block, _uncertainty_block
from .sections.values import _num
from .sections.verdict import _distrust, _kpis
from .sections.views import _view_rows
from .uncertainty import form_sigmas, predicted_point_error


def build_context(folder: ResultFolder, *, qa_cfg: dict, qa_source: str, make_plots: bool = True) -> dict[str, Any]:
    res, obs = folder.result or {}, folder.observations or {}
    mode_known = res.get("mode") in MODES
    mount = mounting(res["mode"]) if mode_known else EYE_IN_HAND  # an unknown mode is shown as such
    x_name, b_name = mount.x_name, mount.board_name
    parent, board_parent = mount.fixed_frame, mount.board_frame
    ok = res.get("status") == "ok"
    ref = ref if isinstance(ref := res.get("refinement"), dict) else {}
    if ref and ref.get("status") not in (None, "ok"):
        ref = {}
    diag = diag if isinstance(diag := res.get("diagnostics"), dict) else {}
    T_x = as_T(res.get(x_name)) if ok else None
    T_board = as_T(res.get(b_name)) if ok else None
    # the verdict covariance when the result has one (the model's or the validated, as the validation found), else
    # the model's
    cov = (
        (
            as_cov6(ref.get("cov_x_6x6_verdict"))
            if ref.get("cov_x_6x6_verdict") is not None
            else as_cov6(ref.get("cov_x_6x6"))
        )
        if ref
        else None
    )
    intr = res.get("intrinsics") or ref.get("intrinsics")
    obj = np.asarray(obs.get("object_points_m") or [], float).reshape(-1, 3)
    board_centre = obj.mean(axis=0) if len(obj) else np.zeros(3)
    fits = view_fits(obs)
    image_size = (intr or {}).get("image_size") or obs.get("image_size")

    wd_cfg = qa_cfg.get("working_distance_m")
    wd = float(wd_cfg) if wd_cfg is not None else _num(ref.get("working_distance_m"))
    if not finite(wd):
        wd = median_board_distance_m(fits, board_centre)

    tracked = is_tracked(res.get("target"))  # a pose-only session: no images, a tracked target for a board
    ctx: dict[str, Any] = {
        "x_name": x_name,
        "board_name": b_name,
        "parent": parent,
        "mode": mount.name,
        "mode_text": _mode_text(mount, tracked=tracked) if mode_known else "Mounting mode unknown",
        "ok": ok,
        "refined": bool(ref),
    }
    ctx["meta"] = _meta(res, obs)
    findings = _findings(diag)
    stages = _stages(diag)
    views = _view_rows(res, ref, fits, board_centre, findings, image_size)
    ctx["views"] = views
    ctx["tracked"] = tracked
    ctx["n_used"] = sum(v["status"] == "used" for v in views)
    ctx["n_total"] = len(views)

    # --- result forms and uncertainty
    unc = form_sigmas(T_x, cov) if T_x is not None and cov is not None else None
    pred = (
        predicted_point_error(T_x, cov, working_distance_m=wd)
        if T_x is not None and cov is not None and finite(wd)
        else None
    )
    ctx["result"] = (
        _result_block(
            res,
            T_x,
            T_board=T_board,
            unc=unc,
            pred=pred,
            wd=wd,
            x_name=x_name,
            b_name=b_name,
            parent=parent,
            board_parent=board_parent,
            tracked=tracked,
        )
        if T_x is not None
        else None
    )
    ctx["uncertainty"] = _uncertainty_block(ref, unc, parent) if unc is not None else None
    ctx["methods"] = _methods(res, T_x, x_name)
    ctx["methods_views"] = methods_views(res)
    ctx["prior"] = _prior_block(res, x_name)
    ctx["offsets"] = _offsets(res, ref, T_x, cov, x_name, tracked=ctx["tracked"])
    ctx["intrinsics"] = _intrinsics_rows(
        intr,
        (ref.get("intrinsics_sigma_verdict") or ref.get("intrinsics_sigma")) if ref else None,
        res,
        model_sigma=ref.get("intrinsics_sigma") if ref else None,
    )
    ctx["noise"] = _noise(ref, tracked=ctx["tracked"])
    ctx["robot_model"] = _robot_model(ref)
    ctx["tracker"] = _tracker(ref)

    # --- metrics and verdict
    metrics, notes = qa_metrics(
        res,
        ref,
        fits,
        views,
        unc,
        pred,
        wd,
        image_size,
        mount,
        coverage_cells_x=int(qa_cfg.get("coverage_grid_cells_x", 16)),
    )
    failure = failure_advice(res, findings, has_views=bool(views)) if not ok else None
    notes["x_name"] = x_name
    notes["intrinsics_fixed"] = "fixed" in str((res.get("intrinsics") or {}).get("source") or "")
    cause = root_cause(res, findings)
    if cause:
        notes["root_cause"] = cause
    untrusted = untrusted_metrics(findings)
    if any(f["severity"] == "fail" for f in findings):  # those checks are shown untrusted: the headline skips them
        notes["headline_skips"] = tuple(untrusted)
    if pred is not None and "predicted_error_mm" not in untrusted:  # the headline repeats it
        notes["predicted_text"] = f"{num(pred['rms_mm'], 2)} mm (1 σ) at {wd:.2f} m"
    verdict = evaluate(
        metrics,
        qa_cfg,
        context=notes,
        failure=failure,
        findings=findings,
        crashed_stages=stages["crashed"],
        thresholds_source=qa_source,
    )
    verdict = _distrust(verdict, untrusted, fail_finding=any(f["severity"] == "fail" for f in findings))
    ctx["verdict"] = verdict
    ctx["untrusted"] = untrusted
    ctx["failure"] = failure
    ctx["root_cause"] = cause
    ctx["verdict_label"] = "REFUSED" if cause and cause["refused"] else verdict.label
    ctx["findings"] = findings
    ctx["stages"] = stages
    ctx["cross_validation"] = _cross_validation(diag.get("cross_validation"))
    ctx["kpis"] = _kpis(metrics, pred, wd, views, verdict, ok, untrusted)
    ctx["motion"] = res.get("motion")
    ctx["provenance"] = _provenance(res, qa_cfg, qa_source)
    ctx["plots"] = []
    ctx["figure_inputs"] = dict(
        res=res,
        obs=obs,
        ref=ref,
        fits=fits,
        views=views,
        T_x=T_x,
        T_board=T_board,
        unc=unc,
        metrics=metrics,
        notes=notes,
        qa_cfg=qa_cfg,
        mounting=mount,
        image_size=image_size,
    )
    if make_plots:
        add_figures(ctx)
    ctx["thumbs"] = {v["id"]: folder.thumbnails[v["id"]] for v in views if v["id"] in folder.thumbnails}
    for v in views:
        v["has_thumb"] = v["id"] in ctx["thumbs"]
    return ctx


def add_figures(ctx: dict, process=None) -> dict:
    """The report's figures (``ctx["plots"]``) for a context built without them.

    The context is built once, judged, and drawn only when a report is written. ``process``: the command's
    :class:`~handeye.report.figure_process.FigureProcess`, which draws them when it can; otherwise (None, or
    it could not) they are drawn here.
    """
    from .figures import report_figures

    plots = process.figures(ctx["figure_inputs"]) if process is not None else None
    ctx["plots"] = plots if plots is not None else report_figures(**ctx["figure_inputs"])
    return ctx


def _mode_text(mount, *, tracked: bool = False) -> str:
    """``Eye-in-hand (camera on the robot's flange, board on the table)``; ``target on the table`` when pose-only."""
    where = f"{'target' if tracked else 'board'} {mount.board_location}"
    return f"{mount.name.replace('_', '-').capitalize()} (camera {mount.camera_location}, {where})"
