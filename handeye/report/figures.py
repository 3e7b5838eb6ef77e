"""Which figures the report has, with their captions, and the data each is drawn from.

On Linux with two or more cores the figures are drawn by two processes: this one and a child forked
after matplotlib is imported (so nothing is imported or pickled twice; only the PNG bytes come back),
each drawing every other figure. Whatever the child does not return (it failed, or fork is not
available) is drawn here, so the report has the same figures either way. A figure that cannot be drawn
is logged and left out; it never costs the report. A command that writes a report forks its figure
process (:mod:`handeye.report.figure_process`) before its own imports; that process runs
:func:`report_figures` (and so this split) when the report is built.
"""

from __future__ import annotations

import logging
import os
import pickle
import select
import signal
import sys
import time
import warnings
from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from ..machine import usable_cores
from ..mounting import MountingMode
from .observations import ViewFit, as_T, finite

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Plot:
    key: str
    title: str
    caption: str
    png: bytes


def _board_outline(obs: dict) -> np.ndarray:
    obj = np.asarray(obs.get("object_points_m") or [], float).reshape(-1, 3)
    if not len(obj):
        return np.array([[0, 0, 0], [0.2, 0, 0], [0.2, 0.15, 0], [0, 0.15, 0]], float)
    lo, hi = obj.min(axis=0), obj.max(axis=0)
    sq = (obs.get("target") or {}).get("square_m") or 0.0
    lo, hi = lo - sq, hi + sq
    return np.array([[lo[0], lo[1], 0], [hi[0], lo[1], 0], [hi[0], hi[1], 0], [lo[0], hi[1], 0]], float)


def report_figures(
    *,
    res: dict,
    obs: dict,
    ref: dict,
    fits: dict[str, ViewFit],
    views: list[dict],
    T_x: Optional[np.ndarray],
    T_board: Optional[np.ndarray],
    unc: Optional[dict],
    metrics: dict,
    notes: dict,
    qa_cfg: dict,
    mounting: MountingMode,
    image_size,
) -> list[Plot]:
    from .plots import (
        image_coverage,
        per_view_bars,
        poses_3d,
        residual_histogram,
        rotation_coverage,
        style,
        translation_uncertainty,
    )

    used = {v["id"] for v in views if v["status"] == "used"}
    flagged = {v["id"] for v in views if v["status"] != "used"}
    lim = qa_cfg.get("checks") or {}
    jobs: list[tuple[str, str, str, Callable[..., bytes]]] = []

    # residual histogram
    cam = [fits[v].residual_px for v in sorted(fits) if v in used and np.all(np.isfinite(fits[v].residual_px))]
    chain = [r for v in sorted(fits) if v in used and (r := fits[v].residual_chain_px) is not None]
    if cam:
        cam_all = np.concatenate(cam)
        if ref and finite(ref.get("sigma_px")):
            sigma, src = float(ref["sigma_px"]), "estimated by the refinement"
        else:
            dof = max(2 * len(cam_all) - 6 * len(cam), 1)
            sigma, src = float(np.sqrt(np.sum(cam_all**2) / dof)), "from the camera-fit residuals"
        chain_all: Optional[np.ndarray] = np.concatenate(chain) if chain else None
        jobs.append(
            (
                "residuals",
                "Residuals against the noise model",
                "Lengths of the corner residuals: filled, each view fitted on its own (camera, intrinsics, "
                "corner detection); outline, the board predicted through the reported robot pose and the result "
                "— the difference between the two is what the robot's pose error adds. The curve is the "
                "distribution the lengths follow when the pixel noise is Gaussian with the stated σ.",
                lambda: residual_histogram(cam_all, chain_all, sigma_px=sigma, sigma_source=src),
            )
        )
    # per-view bars
    if views and any(finite(v["rms_px"]) for v in views):
        rl = lim.get("reprojection_rms_px") or {}
        jobs.append(
            (
                "per_view",
                "Residual per view",
                "RMS residual of each view, fitted on its own (dark) and through the robot chain (light). "
                "Red outlines: views dropped; dashed lines: the QA limits of the session's reprojection RMS "
                + ("(the refined fit" if ref else "(the views' own camera fits")
                + "; the through-robot residuals add the robot's pose error and have no limit), where they fall "
                "within the axis: a limit above it is far above every view.",
                lambda rl=rl: per_view_bars(
                    [v["id"] for v in views],
                    [v["rms_px"] for v in views],
                    [v["chain_rms_px"] for v in views],
                    [v["status"] for v in views],
                    warn_px=rl.get("warn_above"),
                    fail_px=rl.get("fail_above"),
                ),
            )
        )
    # coverage
    if image_size and fits and "coverage_counts" in notes:
        vv = [(vid, f.image_points_px, f.residual_px, vid in flagged) for vid, f in sorted(fits.items())]
        jobs.append(
            (
                "coverage",
                "Image coverage and residual vectors",
                "Left: where the detected corners fall (cell shading = number of corners; outlines = each "
                "view's board). Lens distortion is only known where corners were seen. Right: the camera-fit "
                "residual of every corner, magnified; a systematic pattern (swirl, radial) points at a lens "
                "model that does not fit.",
                lambda: image_coverage(
                    int(image_size[0]),
                    int(image_size[1]),
                    vv,
                    notes["coverage_counts"],
                    coverage_share=float(metrics.get("image_coverage") or 0.0),
                ),
            )
        )
    # robot, camera and board in the base frame
    if T_x is not None and T_board is not None:
        ids = [v["id"] for v in views if v["id"] in fits and fits[v["id"]].T_base_end is not None]
        if ids:
            T_be = np.stack([fits[v].T_base_end for v in ids])  # type: ignore[misc]  # ids: views with a pose
            cams = mounting.T_base_cam(T_x, T_be)
            boards = mounting.T_base_board(T_board, T_be)
            cams = np.broadcast_to(cams, T_be.shape) if cams.ndim == 2 else cams
            boards = np.broadcast_to(boards, T_be.shape) if boards.ndim == 2 else boards
            outline = _board_outline(obs)
            fl = [v in flagged for v in ids]
            moves = mounting.camera_moves
            jobs.append(
                (
                    "poses",
                    "Robot, camera and board",
                    "Robot poses (small axes: x red, y green, z blue) as reported, the camera"
                    + (" at each pose" if moves else "")
                    + " and the board"
                    + ("" if moves else " at each pose")
                    + " under the result, in the robot base frame, seen obliquely and from above. "
                    "Red: views dropped.",
                    lambda: poses_3d(
                        T_base_cams=cams,
                        T_base_ends=T_be,
                        T_base_boards=boards,
                        board_outline=outline,
                        flagged=fl,
                        camera_moves=moves,
                    ),
                )
            )
    # rotation coverage
    rv = notes.get("rotvecs")
    if rv is not None and len(rv):
        rl = lim.get("max_rotation_deg") or {}
        jobs.append(
            (
                "rotations",
                "Rotation coverage",
                "Every pair of used views defines a robot rotation. Left: its axis (a point per pair, folded "
                "into one hemisphere, equal-area; colour = angle). Axes spread over the disk constrain the "
                "hand-eye rotation in all directions; a line or a cluster means one axis is missing. Right: the "
                "rotation angles between view pairs.",
                lambda rl=rl: rotation_coverage(
                    rv, frame=notes.get("axis_frame", ""), warn_deg=rl.get("warn_below"), fail_deg=rl.get("fail_below")
                ),
            )
        )
    # uncertainty
    if T_x is not None:
        meth = []
        for m, e in (res.get("closed_form") or {}).items():
            T = as_T(e.get(mounting.x_name))
            if T is not None:
                meth.append((m, (T[:3, 3] - T_x[:3, 3]) * 1e3))
        cov_t = unc["cov_translation_mm2"] if unc is not None else None
        if cov_t is not None or meth:
            jobs.append(
                (
                    "uncertainty",
                    "Uncertainty of the translation",
                    (
                        "1-σ (solid) and 2-σ (dashed) ellipses of the hand-eye translation from the verdict "
                        "covariance (the one every ± of the report uses)"
                        if cov_t is not None
                        else "No covariance (closed form only)"
                    )
                    + "; markers: the closed-form methods, relative to the result. The closed-form methods treat "
                    "the robot poses as exact and weigh views unevenly"
                    + (", so they scatter more than the refined result" if ref else "")
                    + "; one method far from all others points at weak motion or a bad pose.",
                    lambda: translation_uncertainty(cov_t, meth, frame=mounting.fixed_frame, x_name=mounting.x_name),
                )
            )
    with style():
        pngs = draw_figures({key: draw for key, _, _, draw in jobs})
    return [Plot(key, title, caption, png) for key, title, caption, _ in jobs if (png := pngs.get(key)) is not None]


def _draw(key: str, draw: Callable[[], bytes]) -> Optional[bytes]:
    try:
        return draw()
    except Exception as e:  # noqa: BLE001 - a figure that cannot be drawn must not cost the report
        log.warning("report: figure %s left out (%s: %s)", key, type(e).__name__, e)
        return None


#: the figure child's time: this much plus this factor times what this process took for its own half
CHILD_GRACE_S = 30.0
CHILD_TIME_FACTOR = 10.0


def parallel_drawing() -> bool:
    """Whether to draw in two processes: fork (Linux) and a second core this process may use."""
    if not sys.platform.startswith("linux") or os.environ.get("HANDEYE_FIGURE_PROCESSES") == "1":
        return False
    return usable_cores() >= 2


def draw_figures(draws: dict[str, Callable[[], bytes]]) -> dict[str, Optional[bytes]]:
    """PNG bytes of each figure (None: it could not be drawn), every other one drawn by a forked child.

    Call inside :func:`handeye.report.plots.style` (matplotlib imported, the style set: the child inherits
    both). ``HANDEYE_FIGURE_PROCESSES=1`` draws everything in this process.
    """
    keys = list(draws)
    theirs = keys[1::2] if len(keys) >= 2 and parallel_drawing() else []
    child = _fork_drawing({k: draws[k] for k in theirs}) if theirs else None
    t0 = time.monotonic()
    try:
        out = {k: _draw(k, draws[k]) for k in keys if k not in theirs}
    finally:  # the child is always waited for, also when this process is interrupted
        # a child stuck (a lock another thread held at the fork) is ended once it has had ample time
        limit = CHILD_GRACE_S + CHILD_TIME_FACTOR * (time.monotonic() - t0)
        got = _collect(child, limit) if child is not None else {}
    for k in theirs:  # the child's figures, or drawn here when it returned none
        out[k] = got[k] if k in got else _draw(k, draws[k])
    return {k: out[k] for k in keys}


def _fork_drawing(draws: dict[str, Callable[[], bytes]]) -> Optional[tuple[int, int]]:
    """(pid, read end of its pipe) of a child drawing ``draws``, or None when it could not be started."""
    try:
        r, w = os.pipe()
    except OSError:
        return None
    try:
        pid = fork_quietly()
    except OSError as e:
        log.debug("report: figures drawn in one process (fork: %s)", e)
        os.close(r)
        os.close(w)
        return None
    if pid == 0:  # the child: draw, send {key: png or None}, leave without running any exit handler
        code = 1
        try:
            os.close(r)
            data = pickle.dumps({k: _draw(k, d) for k, d in draws.items()})
            with os.fdopen(w, "wb") as f:
                f.write(data)
            code = 0
        except BaseException:  # noqa: BLE001 - the child must end here whatever happens; the parent redraws
            pass
        finally:
            os._exit(code)
    os.close(w)
    return pid, r


def _collect(child: tuple[int, int], limit_s: float) -> dict[str, Optional[bytes]]:
    """The child's figures, or {} when it failed or took longer than ``limit_s`` (the parent then draws them)."""
    pid, r = child
    raw = None
    try:
        raw = read_all(r, deadline=time.monotonic() + limit_s)
        if raw is None:
            log.debug("report: the figure process took over %.0f s; its figures are drawn here", limit_s)
            os.kill(pid, signal.SIGKILL)
    finally:
        os.close(r)
        _, status = os.waitpid(pid, 0)
    if raw is None or not (os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0):
        log.debug("report: the figure process ended with status %s; its figures are drawn here", status)
        return {}
    try:
        got = pickle.loads(raw)
    except (pickle.UnpicklingError, EOFError, ValueError):
        return {}
    return got if isinstance(got, dict) else {}


def fork_quietly() -> int:
    """``os.fork()`` without Python 3.12+'s warning of a fork in a process with threads (raises OSError).

    The threads here are OpenCV's and the BLAS's idle pools; a forked child only draws (matplotlib, PIL,
    numpy) and leaves with ``os._exit``, and whatever it fails to return is drawn by its parent.
    """
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=DeprecationWarning, message=".*fork.*")
        return os.fork()


def write_all(fd: int, data: bytes, *, deadline: Optional[float] = None) -> bool:
    """Write all of ``data``; False when ``deadline`` (monotonic) passed first (the reader is stuck)."""
    view = memoryview(data)
    if deadline is not None:
        os.set_blocking(fd, False)
    while view:
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([], [fd], [], left)[1]:
                return False
        try:
            view = view[os.write(fd, view) :]
        except BlockingIOError:
            continue
    return True


def read_all(fd: int, *, deadline: Optional[float]) -> Optional[bytes]:
    """Everything until the writer closes its end; None when ``deadline`` (monotonic) passed first."""
    chunks: list[bytes] = []
    while True:
        if deadline is not None:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                return None
        chunk = os.read(fd, 1 << 20)
        if not chunk:
            return b"".join(chunks)
        chunks.append(chunk)
