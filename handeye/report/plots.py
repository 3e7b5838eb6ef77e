"""The report's figures: each function draws one figure from plain numpy arrays and returns PNG bytes.

matplotlib is imported when the first figure is drawn (never with the CLI or the pipeline). Drawing
is kept light, because it is most of a report's cost: an Agg canvas without pyplot state, fixed
margins instead of a layout engine, one collection per kind of line instead of one artist per line,
2-D projections instead of mplot3d, and 8-bit palette PNGs. Nothing here reads files.
"""

from __future__ import annotations

import contextlib
import io
from typing import Optional, Sequence

import numpy as np

from .uncertainty import ellipse_points

INK = "#1d2733"
MUTED = "#6b7686"
GRID = "#e3e7ee"
NAVY = "#24476b"
TEAL = "#2a9d8f"
SKY = "#8fb8de"
AMBER = "#d99a2b"
RED = "#c0392b"
ORANGE = "#e07b39"
AXIS_RGB = ("#d62728", "#2ca02c", "#1f77b4")  # x, y, z
DPI = 100
WIDTH_IN = 8.6

_RC = {
    "font.family": "DejaVu Sans",
    "font.size": 8.5,
    "axes.titlesize": 9.5,
    "axes.titleweight": "bold",
    "axes.titlelocation": "left",
    "axes.labelsize": 8.5,
    "axes.edgecolor": "#b9c1cc",
    "axes.labelcolor": INK,
    "axes.titlecolor": INK,
    "xtick.color": MUTED,
    "ytick.color": MUTED,
    "axes.grid": True,
    "grid.color": GRID,
    "grid.linewidth": 0.7,
    "legend.frameon": False,
    "legend.fontsize": 7.8,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "path.simplify": True,
    "axes.titley": 1.0,  # a fixed title position: no tick-label bounding boxes measured to place it
    "axes.titlepad": 5.0,
    "axes.xmargin": 0.02,
}


@contextlib.contextmanager
def style():
    """The report's matplotlib style, for a whole batch of figures (one rc context, not one per call)."""
    import matplotlib

    with matplotlib.rc_context(_RC):
        yield


def _fig(h: float, *, left=0.07, right=0.98, bottom=0.15, top=0.88, wspace=0.25):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(WIDTH_IN, h), dpi=DPI)
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=left, right=right, bottom=bottom, top=top, wspace=wspace)
    return fig


def _png(fig) -> bytes:
    """Render once and encode as an adaptive-palette PNG (a third of the bytes of RGB, same look)."""
    from PIL import Image

    fig.canvas.draw()
    rgb = np.asarray(fig.canvas.buffer_rgba())[:, :, :3]
    img = Image.fromarray(np.ascontiguousarray(rgb)).quantize(
        colors=128, method=Image.Quantize.FASTOCTREE, dither=Image.Dither.NONE
    )
    buf = io.BytesIO()
    img.save(buf, format="png", compress_level=6)
    return buf.getvalue()


@contextlib.contextmanager
def _no_grid():
    """Axes created inside have no grid (switching it off afterwards touches every tick again)."""
    import matplotlib

    was = matplotlib.rcParams["axes.grid"]
    matplotlib.rcParams["axes.grid"] = False
    try:
        yield
    finally:
        matplotlib.rcParams["axes.grid"] = was


def _bars(ax, x: np.ndarray, height: np.ndarray, width: float, *, color, edgecolors, label: str) -> None:
    """Bars as one collection (``ax.bar`` makes an artist per bar)."""
    from matplotlib.collections import PolyCollection

    x0, x1 = x - width / 2, x + width / 2
    h = np.nan_to_num(np.asarray(height, float))
    verts = np.stack(
        [
            np.stack([x0, np.zeros_like(h)], 1),
            np.stack([x0, h], 1),
            np.stack([x1, h], 1),
            np.stack([x1, np.zeros_like(h)], 1),
        ],
        axis=1,
    )
    ax.add_collection(
        PolyCollection(
            verts,  # type: ignore[arg-type]  # an (n, 4, 2) array of polygons
            facecolors=color,
            edgecolors=edgecolors,
            linewidths=1.2,
            label=label,
        )
    )
    ax.update_datalim([(float(x0.min()), 0.0), (float(x1.max()), float(h.max(initial=0.0)))])


def _few_ticks(*axes, n: int = 5) -> None:
    """At most ``n`` ticks per axis: every tick is several artists, and ticks are most of a figure's cost."""
    from matplotlib.ticker import MaxNLocator

    for ax in axes:
        ax.xaxis.set_major_locator(MaxNLocator(n))
        ax.yaxis.set_major_locator(MaxNLocator(n))


def _lines(ax, segments, **kw):
    """Many line segments / polylines as one artist."""
    from matplotlib.collections import LineCollection

    if len(segments):
        ax.add_collection(LineCollection(segments, **kw))


def _hull(pts: np.ndarray) -> np.ndarray:
    """Convex hull (monotone chain) of 2-D points, counter-clockwise, without repeating the first."""
    p = [tuple(q) for q in np.unique(np.asarray(pts, float), axis=0).tolist()]
    if len(p) < 3:
        return np.asarray(p, float).reshape(-1, 2)

    def half(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
        out: list[tuple[float, float]] = []
        for x, y in points:
            while (
                len(out) >= 2
                and ((out[-1][0] - out[-2][0]) * (y - out[-2][1]) - (out[-1][1] - out[-2][1]) * (x - out[-2][0])) <= 0
            ):
                out.pop()
            out.append((x, y))
        return out

    lower, upper = half(p), half(p[::-1])
    return np.array(lower[:-1] + upper[:-1], float)


# ------------------------------------------------------------------------------ residuals
def residual_histogram(
    camera_px: np.ndarray, chain_px: Optional[np.ndarray], *, sigma_px: float, sigma_source: str
) -> bytes:
    """Corner residual lengths against the Rayleigh law of a 2-D Gaussian.

    Corner residual lengths (camera fit, and through the robot) against the Rayleigh law of a 2-D
    Gaussian with ``sigma_px`` per axis.
    """
    fig = _fig(2.9, left=0.07, bottom=0.16, top=0.9)
    ax = fig.add_subplot()
    e = np.linalg.norm(np.asarray(camera_px, float).reshape(-1, 2), axis=1)
    e = e[np.isfinite(e)]
    ec = None if chain_px is None else np.linalg.norm(np.asarray(chain_px, float).reshape(-1, 2), axis=1)
    ec = ec[np.isfinite(ec)] if ec is not None else None
    both = np.concatenate([e, ec]) if ec is not None and len(ec) else e
    hi = max(
        float(np.quantile(both, 0.995)) if len(both) else 0.0, 4.0 * sigma_px if np.isfinite(sigma_px) else 0.0, 1e-6
    )
    bins = np.linspace(0.0, hi, 40)
    if len(e):
        ax.hist(
            np.clip(e, 0, hi),
            bins=bins,
            density=True,
            histtype="stepfilled",
            color=NAVY,
            alpha=0.7,
            label=f"camera fit: {len(e)} corners, RMS {np.sqrt(np.mean(e**2)):.3f} px",
        )
    if ec is not None and len(ec):
        ax.hist(
            np.clip(ec, 0, hi),
            bins=bins,
            density=True,
            histtype="step",
            color=TEAL,
            lw=1.6,
            label=f"through the robot: RMS {np.sqrt(np.mean(ec**2)):.3f} px",
        )
    if np.isfinite(sigma_px) and sigma_px > 0:
        x = np.linspace(0.0, hi, 200)
        ax.plot(
            x,
            x / sigma_px**2 * np.exp(-0.5 * (x / sigma_px) ** 2),
            color=ORANGE,
            lw=1.6,
            label=f"expected (σ = {sigma_px:.3f} px/axis, {sigma_source})",
        )
    ax.set_title("Corner residual lengths")
    ax.set_xlabel("residual length [px]")
    ax.set_ylabel("density")
    _few_ticks(ax, n=6)
    ax.set_xlim(0, hi)
    ax.set_ylim(0, ax.get_ylim()[1] * 1.3)
    ax.legend(loc="upper right")
    return _png(fig)


def per_view_bars(
    ids: Sequence[str],
    camera_rms: Sequence[float],
    chain_rms: Sequence[float],
    status: Sequence[str],
    *,
    warn_px: Optional[float],
    fail_px: Optional[float],
) -> bytes:
    """Per-view RMS: camera fit and through the robot; dropped views marked, QA limits drawn."""
    n = len(ids)
    fig = _fig(2.8, bottom=0.2 if n > 24 else 0.16, top=0.84)
    ax = fig.add_subplot()
    x = np.arange(n, dtype=float)
    cam = np.array([v if v is not None and np.isfinite(v) else np.nan for v in camera_rms], float)
    ch = np.array([v if v is not None and np.isfinite(v) else np.nan for v in chain_rms], float)
    w = 0.38
    edge = [RED if s in ("flagged", "dropped") else "none" for s in status]
    _bars(ax, x - w / 2, cam, w, color=NAVY, edgecolors=edge, label="camera fit RMS")
    if np.any(np.isfinite(ch)):
        _bars(ax, x + w / 2, ch, w, color=SKY, edgecolors=edge, label="through the robot RMS")
    allv = np.concatenate([cam, ch])
    allv = allv[np.isfinite(allv)]
    top = float(np.max(allv)) if len(allv) else 0.1
    typical = float(np.quantile(allv, 0.75)) if len(allv) else 0.1
    cap = max(4.0 * typical, (fail_px or 0.0) * 1.3, (warn_px or 0.0) * 1.3, 0.1)
    clipped = top > 1.05 * cap
    if clipped:  # one gross outlier must not flatten every other bar: cut the axis, print the value
        top = cap
        for xi, c, h in zip(x, cam, ch, strict=False):
            for off, val in ((-w / 2, c), (w / 2, h)):
                if np.isfinite(val) and val > cap:
                    ax.text(
                        xi + off,
                        cap * 0.97,
                        f"{val:.0f} px ↑" if val >= 10 else f"{val:.1f} px ↑",
                        ha="center",
                        va="top",
                        fontsize=7,
                        color="white",
                        fontweight="bold",
                        rotation=90,
                    )
    for xi, s, c in zip(x, status, cam, strict=False):
        if s == "dropped" and not np.isfinite(c):
            ax.text(xi, top * 0.04, "dropped", rotation=90, ha="center", va="bottom", fontsize=7, color=RED)
    if warn_px is not None and warn_px < top * 1.3:
        ax.axhline(warn_px, color=AMBER, lw=1.0, ls="--", label=f"QA warn {warn_px:g} px")
    if fail_px is not None and fail_px < top * 1.3:
        ax.axhline(fail_px, color=RED, lw=1.0, ls="--", label=f"QA fail {fail_px:g} px")
    ax.set_xticks(x)
    ax.set_xticklabels(ids, rotation=90 if n > 24 else 0, fontsize=7.5 if n > 24 else 8)
    ax.set_xlim(-0.7, n - 0.3)
    ax.set_xlabel("view id")
    ax.set_ylabel("RMS [px]")
    ax.xaxis.grid(False)
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=4, borderaxespad=0.2)
    ax.set_ylim(0, top * (1.0 if clipped else 1.1))
    return _png(fig)


def _nice(x: float) -> float:
    if not np.isfinite(x) or x <= 0:
        return 1.0
    e = 10 ** np.floor(np.log10(x))
    for m in (1, 2, 5, 10):
        if m * e >= x * 0.75:
            return float(m * e)
    return float(10 * e)


def image_coverage(
    width: int, height: int, views: Sequence[tuple], counts: np.ndarray, *, coverage_share: float
) -> bytes:
    """Image coverage of the corners (left) and magnified camera-fit residual vectors (right).

    Left: which parts of the image the corners reach (cell counts, each view's outline).
    Right: camera-fit residual vectors, magnified. ``views``: (id, points (N,2), residuals (N,2), flagged).
    """
    from matplotlib.colors import LinearSegmentedColormap

    aspect = height / max(width, 1)
    fig = _fig(WIDTH_IN / 2 * aspect + 0.6, left=0.07, right=0.99, bottom=0.1, top=0.92, wspace=0.12)
    with _no_grid():
        ax, ax2 = fig.subplots(1, 2)
    ax.set_title(f"Corner coverage: {coverage_share:.0%} of the image")
    cmap = LinearSegmentedColormap.from_list("cov", ["#ffffff", "#cfe0f1", "#5b8fc4", NAVY])
    ax.imshow(
        np.ma.masked_where(counts == 0, counts),
        extent=(0, width, height, 0),
        cmap=cmap,
        interpolation="nearest",
        aspect="equal",
        vmin=0,
        vmax=max(1, counts.max()),
        alpha=0.9,
    )
    for flagged in (False, True):
        hulls = [_hull(pts) for _, pts, _, f in views if f == flagged and len(pts) >= 3]
        _lines(
            ax,
            [np.vstack([h, h[:1]]) for h in hulls if len(h) >= 3],
            colors=RED if flagged else MUTED,
            linewidths=0.7,
            alpha=0.8,
        )
    ok = [(p, r, f) for _, p, r, f in views if len(p) and np.all(np.isfinite(r))]
    allr = np.concatenate([r for _, r, _ in ok]) if ok else np.zeros((0, 2))
    ref = float(np.quantile(np.linalg.norm(allr, axis=1), 0.9)) if len(allr) else 1.0
    gain = _nice(0.045 * width / max(ref, 1e-9))
    ax2.set_title(f"Camera-fit residuals, magnified {gain:g}×")
    for flagged, color in ((False, NAVY), (True, RED)):
        seg = [np.stack([p, p + gain * r], axis=1) for p, r, f in ok if f == flagged]
        if seg:
            _lines(ax2, np.concatenate(seg), colors=color, linewidths=0.8, alpha=0.85)
    sx, sy = 0.06 * width, 0.94 * height
    one = _nice(ref) if ref > 0 else 1.0
    ax2.plot([sx, sx + one * gain], [sy, sy], color=INK, lw=1.6)
    ax2.text(sx, sy - 0.025 * height, f"{one:g} px", fontsize=7.5, color=INK)
    for a in (ax, ax2):
        a.plot([0, width, width, 0, 0], [0, 0, height, height, 0], color="#9aa5b4", lw=1.0)
        a.set_xlim(-0.02 * width, 1.02 * width)
        a.set_ylim(1.02 * height, -0.02 * height)
        a.set_aspect("equal")
        a.set_xlabel("u [px]")
    _few_ticks(ax, ax2)
    ax.set_ylabel("v [px]")
    return _png(fig)


# ------------------------------------------------------------------------------ geometry
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

    Robot base, end poses, cameras and board(s) in the base frame: an oblique and a top view
    (orthographic projections drawn in 2-D). ``camera_moves``: a camera per pose (eye-in-hand), else a
    board per pose.
    """
    from matplotlib.collections import PolyCollection

    flagged = np.asarray(flagged, bool)
    pts = np.concatenate([T_base_cams[:, :3, 3], T_base_ends[:, :3, 3], T_base_boards[:, :3, 3], np.zeros((1, 3))])
    L = 0.07 * (float(np.max(np.ptp(pts, axis=0))) or 1.0)
    fig = _fig(3.9, left=0.02, right=0.99, bottom=0.12, top=0.92, wspace=0.08)
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
                ax.plot([], [], color=RED, label="dropped or flagged view")
            ax.legend(loc="best", fontsize=7)
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
    for r0, lab in rings:
        ax.text(r0 * np.cos(np.radians(75)), r0 * np.sin(np.radians(75)), lab, fontsize=6.5, color=MUTED)
    vmax = max(90.0, float(np.degrees(ang.max())) if len(ang) else 90.0)
    ax.scatter(
        rr * np.cos(phi),
        rr * np.sin(phi),
        c=np.degrees(ang[keep]),
        cmap="viridis",
        s=10,
        vmin=0,
        vmax=vmax,
        edgecolor="none",
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
