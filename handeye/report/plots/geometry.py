"""The geometry figures: robot, camera and board poses, rotation coverage, translation uncertainty."""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from ..uncertainty import ellipse_points
from .canvas import (
    AMBER,
    AXIS_RGB,
    GRID,
    INK,
    MUTED,
    NAVY,
    ORANGE,
    RED,
    _few_ticks,
    _fig,
    _lines,
    _no_grid,
    _png,
)

_CAM_CORNERS = np.array([[-0.6, -0.45, 1.0], [0.6, -0.45, 1.0], [0.6, 0.45, 1.0], [-0.6, 0.45, 1.0]])


def _view_matrix(elev_deg: float, azim_deg: float) -> np.ndarray:
    """(2, 3) orthographic projection onto the screen of a camera at the given elevation and azimuth."""
    e, a = np.radians(elev_deg), np.radians(azim_deg)
    right = np.array([-np.sin(a), np.cos(a), 0.0])
    up = np.array([-np.sin(e) * np.cos(a), -np.sin(e) * np.sin(a), np.cos(e)])
    return np.stack([right, up])


def poses_3d(
    *,
    T_base_cams: np.ndarray,
    T_base_ends: np.ndarray,
    T_base_boards: np.ndarray,
    board_outline: np.ndarray,
    flagged: Sequence[bool] | np.ndarray,
    camera_moves: bool,
) -> bytes:
    """Robot base, end poses, cameras and board(s) in the base frame: an oblique and a top view.

    Orthographic projections drawn in 2-D, with one legend in a row under both views (inside a view it can
    hide the poses it explains). ``camera_moves``: a camera per pose (eye-in-hand), else a board per pose.
    """
    from matplotlib.collections import PolyCollection

    flagged = np.asarray(flagged, bool)
    pts = np.concatenate([T_base_cams[:, :3, 3], T_base_ends[:, :3, 3], T_base_boards[:, :3, 3], np.zeros((1, 3))])
    L = 0.07 * (float(np.max(np.ptp(pts, axis=0))) or 1.0)
    fig = _fig(4.2, left=0.02, right=0.99, bottom=0.2, top=0.92, wspace=0.08)
    views = [
        ("Oblique view (elevation 24°, azimuth −58°)", _view_matrix(24, -58), False),
        ("Top view (base x–y)", np.array([[1.0, 0, 0], [0, 1.0, 0]]), True),
    ]
    for k, (title, P, labelled) in enumerate(views):
        if labelled:
            ax = fig.add_subplot(1, 2, k + 1)
        else:
            with _no_grid():
                ax = fig.add_subplot(1, 2, k + 1)
        ax.set_title(title)

        def proj(p, P=P):
            return np.asarray(p, float) @ P.T

        # robot end triads (as reported) and the base
        for a, color in enumerate(AXIS_RGB):
            o = T_base_ends[:, :3, 3]
            seg = np.stack([proj(o), proj(o + 0.6 * L * T_base_ends[:, :3, a])], axis=1)
            _lines(ax, seg, colors=color, linewidths=0.8, alpha=0.7)
            _lines(ax, [np.stack([proj(np.zeros(3)), proj(1.6 * L * np.eye(3)[a])])], colors=color, linewidths=2.0)
        ax.text(*proj(np.zeros(3)), " base", fontsize=7.5, color=INK, va="top")
        # the moving part at every pose, the fixed one once
        for bad in (False, True):
            sel = np.flatnonzero(flagged == bad)
            if camera_moves:
                _lines(
                    ax,
                    [proj(_frustum(T_base_cams[i], 0.9 * L)) for i in sel],
                    colors=RED if bad else NAVY,
                    linewidths=0.8,
                )
            else:
                polys = [proj(transform(T_base_boards[i], board_outline)) for i in sel]
                if polys:
                    ax.add_collection(
                        PolyCollection(polys, facecolors=RED if bad else ORANGE, alpha=0.3, edgecolors="none")
                    )
            # dotted link from the flange to what it carries
            carried = T_base_cams if camera_moves else T_base_boards
            _lines(
                ax,
                [proj(np.stack([T_base_ends[i, :3, 3], carried[i, :3, 3]])) for i in sel],
                colors=RED if bad else MUTED,
                linewidths=0.5,
                linestyles=":",
                alpha=0.6,
            )
        if camera_moves:
            B = proj(transform(T_base_boards[0], board_outline))
            ax.fill(B[:, 0], B[:, 1], color=ORANGE, alpha=0.5, lw=0)
            ax.text(*B.mean(axis=0), " board", fontsize=7.5, color=ORANGE)
        else:
            F = proj(_frustum(T_base_cams[0], 1.4 * L))
            ax.plot(F[:, 0], F[:, 1], color=NAVY, lw=1.3)
            ax.text(*F[0], " camera", fontsize=7.5, color=NAVY)
        Q = proj(pts)
        ax.update_datalim(np.vstack([Q.min(axis=0) - L, Q.max(axis=0) + L]))
        ax.autoscale_view()
        ax.set_aspect("equal", adjustable="datalim")
        if labelled:
            _few_ticks(ax)
            ax.set_xlabel("x [m]")
            ax.set_ylabel("y [m]")
            ax.plot([], [], color=MUTED, label="robot end (flange), x y z")
            ax.plot([], [], color=NAVY, label="camera")
            ax.fill([], [], color=ORANGE, alpha=0.4, label="board")
            if flagged.any():
                ax.plot([], [], color=RED, label="dropped view")
            handles, labels = ax.get_legend_handles_labels()
            fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=7, frameon=False)
        else:
            ax.set_xticks([])
            ax.set_yticks([])
    return _png(fig)


def transform(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    return np.asarray(p, float) @ T[:3, :3].T + T[:3, 3]


def _frustum(T: np.ndarray, L: float) -> np.ndarray:
    """Outline of a camera pyramid as one polyline (11, 3)."""
    P = transform(T, _CAM_CORNERS * L)
    o = T[:3, 3]
    return np.array([o, P[0], P[1], o, P[2], P[3], o, P[0], P[3], P[2], P[1]])


def _label_angle(pts: np.ndarray, radii: list) -> float:
    """The angle (rad) whose ray crosses the rings where the fewest points lie, 75° the first of equals."""
    best, th = None, np.radians(75.0)
    for deg in (75, *range(0, 360, 15)):
        c = np.radians(deg)
        at = np.array([[r * np.cos(c), r * np.sin(c)] for r in radii])  # shape (rings, 2)
        n = int((np.linalg.norm(pts[:, None, :] - at[None], axis=2) < 0.12).sum()) if len(pts) else 0
        if best is None or n < best:
            best, th = n, c
    return float(th)


def rotation_coverage(
    rotvecs: np.ndarray, *, frame: str, warn_deg: Optional[float], fail_deg: Optional[float]
) -> bytes:
    """Axes of the pairwise robot rotations on an equal-area disk (hemisphere, sign folded) and their angles."""
    rv = np.asarray(rotvecs, float).reshape(-1, 3)
    ang = np.linalg.norm(rv, axis=1)
    fig = _fig(3.3, left=0.02, right=0.98, bottom=0.14, top=0.9, wspace=0.15)
    gs = fig.add_gridspec(1, 2, width_ratios=[1.0, 1.5])
    ax = fig.add_subplot(gs[0])
    ax.set_title(f"Rotation axes ({frame} frame)")
    keep = ang > np.radians(2.0)
    a = rv[keep] / ang[keep, None] if keep.any() else np.zeros((0, 3))
    a = np.where(a[:, 2:3] < 0, -a, a)  # fold to the upper hemisphere (axis and -axis are one line)
    rr = np.sqrt(np.clip(1.0 - a[:, 2], 0.0, None))  # Lambert azimuthal equal-area projection
    phi = np.arctan2(a[:, 1], a[:, 0])
    t = np.linspace(0, 2 * np.pi, 120)
    rings = [(np.sqrt(1 - np.cos(np.radians(d))), f"{d}°") for d in (30, 60, 90)]
    _lines(
        ax,
        [np.stack([r0 * np.cos(t), r0 * np.sin(t)], axis=1) for r0, _ in rings]
        + [np.array([[-1, 0], [1, 0]]), np.array([[0, -1], [0, 1]])],
        colors=GRID,
        linewidths=0.8,
    )
    vmax = max(90.0, float(np.degrees(ang.max())) if len(ang) else 90.0)
    pts = np.stack([rr * np.cos(phi), rr * np.sin(phi)], axis=1)
    ax.scatter(pts[:, 0], pts[:, 1], c=np.degrees(ang[keep]), cmap="viridis", s=10, vmin=0, vmax=vmax, edgecolor="none")
    th = _label_angle(pts, [r0 for r0, _ in rings])
    for r0, lab in rings:  # over the points, where fewest of them lie, on a pale box
        ax.text(
            r0 * np.cos(th),
            r0 * np.sin(th),
            lab,
            fontsize=6.5,
            color=MUTED,
            ha="center",
            va="center",
            zorder=3,
            bbox={"boxstyle": "round,pad=0.1", "facecolor": "white", "edgecolor": "none", "alpha": 0.8},
        )
    ax.text(1.04, 0, "+x", fontsize=7.5, va="center")
    ax.text(0, 1.05, "+y", fontsize=7.5, ha="center")
    ax.text(
        0.0,
        -1.15,
        f"rings: tilt from +z · colour: angle 0–{vmax:.0f}° (viridis)",
        fontsize=6.8,
        color=MUTED,
        ha="center",
    )
    ax.set_xlim(-1.15, 1.15)
    ax.set_ylim(-1.2, 1.15)
    ax.set_aspect("equal")
    ax.axis("off")
    ax2 = fig.add_subplot(gs[1])
    ax2.set_title(f"Rotation between view pairs ({len(ang)} pairs)")
    if len(ang):
        ax2.hist(
            np.degrees(ang),
            bins=np.linspace(0, max(180.0, np.degrees(ang.max())), 37),
            color=NAVY,
            histtype="stepfilled",
            alpha=0.8,
        )
    if fail_deg is not None:
        ax2.axvline(fail_deg, color=RED, ls="--", lw=1.0, label=f"QA fail < {fail_deg:g}° (largest)")
    if warn_deg is not None:
        ax2.axvline(warn_deg, color=AMBER, ls="--", lw=1.0, label=f"QA warn < {warn_deg:g}° (largest)")
    _few_ticks(ax2, n=6)
    ax2.set_xlabel("relative rotation [deg]")
    ax2.set_ylabel("view pairs")
    ax2.set_xlim(0, 180)
    ax2.legend(loc="upper right")
    return _png(fig)


def translation_uncertainty(
    cov_t_mm2: Optional[np.ndarray], methods: Sequence[tuple], *, frame: str, x_name: str
) -> bytes:
    """1- and 2-sigma ellipses of the translation.

    1- and 2-sigma ellipses of the translation (three planes of ``frame``), with the closed-form methods
    as points relative to the result. ``methods``: (name, offset_mm (3,)).
    """
    fig = _fig(3.0, left=0.095, right=0.8, bottom=0.16, top=0.84, wspace=0.5)
    axs = fig.subplots(1, 3)
    lab = "xyz"
    off = np.array([m[1] for m in methods]) if methods else np.zeros((0, 3))
    if cov_t_mm2 is not None:  # the view is the uncertainty; methods beyond it are marked at the border
        lim = 3.5 * float(np.sqrt(np.max(np.diag(cov_t_mm2))))
        if len(off):
            near = np.max(np.abs(off), axis=1)
            near = near[near <= 4.0 * lim]
            if len(near):
                lim = max(lim, 1.15 * float(near.max()))
    else:
        lim = 1.15 * float(np.max(np.abs(off))) if len(off) else 1.0
    lim = lim or 1.0
    n_out = int(np.sum(np.max(np.abs(off), axis=1) > lim)) if len(off) else 0
    markers = "osD^v<>ph*"
    for k, (i, j) in enumerate([(0, 1), (0, 2), (1, 2)]):
        ax = axs[k]
        ax.set_title(f"{lab[i]}–{lab[j]} plane")
        if cov_t_mm2 is not None:
            C = cov_t_mm2[np.ix_([i, j], [i, j])]
            for ks, ls, a in ((1.0, "-", 0.22), (2.0, "--", 0.08)):
                E = ellipse_points(C, k_sigma=ks, n=72)
                ax.fill(E[:, 0], E[:, 1], color=NAVY, alpha=a, lw=0)
                ax.plot(E[:, 0], E[:, 1], color=NAVY, lw=1.0, ls=ls, label=f"{ks:g} σ" if k == 0 else None)
        ax.plot([0], [0], marker="+", color=INK, ms=9, mew=1.5, ls="none", label="result" if k == 0 else None)
        for n, (name, o) in enumerate(methods):
            px, py = o[i], o[j]
            outside = max(abs(px), abs(py)) > lim
            if outside:  # pin to the border along its direction, hollow marker
                f = 0.97 * lim / max(abs(px), abs(py))
                px, py = px * f, py * f
            ax.plot(
                px,
                py,
                marker=markers[n % len(markers)],
                ms=4.5,
                ls="none",
                color=f"C{n % 10}",
                mfc="none" if outside else f"C{n % 10}",
                label=name if k == 0 else None,
                alpha=0.9,
            )
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.set_xlabel(f"Δ{lab[i]} [mm]")
        ax.set_ylabel(f"Δ{lab[j]} [mm]")
        _few_ticks(ax, n=3)
    handles, labels = axs[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="center left", bbox_to_anchor=(0.81, 0.5), fontsize=7.5)
    note = f"; hollow: {n_out} beyond the range, at the border" if n_out else ""
    fig.suptitle(
        f"Translation of {x_name} ({frame} frame), offsets from the result{note}",
        fontsize=9.5,
        fontweight="bold",
        x=0.01,
        ha="left",
        color=INK,
    )
    return _png(fig)
