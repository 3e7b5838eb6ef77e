"""The report's figures (matplotlib, Agg, no pyplot state): each function returns PNG bytes.

Inputs are plain numpy arrays prepared by :mod:`handeye.report.build`; nothing here reads files.
"""
from __future__ import annotations

import io
from typing import Optional, Sequence

import matplotlib

matplotlib.use("Agg", force=False)
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Polygon, Rectangle  # noqa: E402

from .analysis import ellipse_points  # noqa: E402

INK = "#1d2733"
MUTED = "#6b7686"
GRID = "#e3e7ee"
NAVY = "#24476b"
TEAL = "#2a9d8f"
SKY = "#8fb8de"
AMBER = "#d99a2b"
RED = "#c0392b"
GREEN = "#2e8b57"
ORANGE = "#e07b39"
DPI = 100

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
}


def _fig(w: float, h: float) -> Figure:
    with matplotlib.rc_context(_RC):
        fig = Figure(figsize=(w, h), dpi=DPI, layout="constrained")
    return fig


def _png(fig: Figure) -> bytes:
    buf = io.BytesIO()
    with matplotlib.rc_context(_RC):
        # fast zlib level: the PNGs are embedded once, encoding time matters more than bytes
        fig.savefig(buf, format="png", dpi=DPI, facecolor="white", pil_kwargs={"compress_level": 1})
    return buf.getvalue()


def _styled(fn):
    def wrapper(*a, **k):
        with matplotlib.rc_context(_RC):
            return fn(*a, **k)

    wrapper.__name__ = fn.__name__
    wrapper.__doc__ = fn.__doc__
    return wrapper


# ------------------------------------------------------------------------------ residuals
@_styled
def residual_histogram(camera_px: np.ndarray, chain_px: Optional[np.ndarray], *, sigma_px: float,
                       sigma_source: str) -> bytes:
    """Histogram of corner residual lengths against the Rayleigh law of a 2-D Gaussian with ``sigma_px``."""
    fig = _fig(8.6, 3.0)
    axs = fig.subplots(1, 2)
    panels = [(axs[0], camera_px, "Camera fit (each view's own board pose)", NAVY)]
    panels.append((axs[1], chain_px, "Through the robot (reported pose and result)", TEAL))
    for ax, r, title, color in panels:
        ax.set_title(title)
        if r is None or not len(r):
            ax.text(0.5, 0.5, "not available", ha="center", va="center", transform=ax.transAxes, color=MUTED)
            ax.set_xticks([])
            ax.set_yticks([])
            continue
        e = np.linalg.norm(np.asarray(r, float).reshape(-1, 2), axis=1)
        hi = max(float(np.quantile(e, 0.995)), 4.0 * sigma_px if np.isfinite(sigma_px) else 0.0, 1e-6)
        bins = np.linspace(0.0, hi, 40)
        ax.hist(np.clip(e, 0, hi), bins=bins, density=True, color=color, alpha=0.75, edgecolor="white",
                linewidth=0.4, label=f"{len(e)} corners, RMS {np.sqrt(np.mean(e ** 2)):.2f} px")
        if np.isfinite(sigma_px) and sigma_px > 0:
            x = np.linspace(0.0, hi, 300)
            pdf = x / sigma_px ** 2 * np.exp(-0.5 * (x / sigma_px) ** 2)
            ax.plot(x, pdf, color=ORANGE, lw=1.6, label=f"expected (σ = {sigma_px:.2f} px/axis, {sigma_source})")
        ax.set_xlabel("residual length [px]")
        ax.set_ylabel("density")
        ax.set_xlim(0, hi)
        ax.set_ylim(0, ax.get_ylim()[1] * 1.32)
        ax.legend(loc="upper right", frameon=True, facecolor="white", edgecolor="none", framealpha=0.9)
    return _png(fig)


@_styled
def per_view_bars(ids: Sequence[str], camera_rms: Sequence[float], chain_rms: Sequence[float],
                  status: Sequence[str], *, warn_px: Optional[float], fail_px: Optional[float]) -> bytes:
    """Per-view RMS: camera fit and through the robot; dropped views marked, QA limits drawn."""
    n = len(ids)
    fig = _fig(8.6, 2.9)
    ax = fig.subplots()
    x = np.arange(n)
    cam = np.array([v if v is not None and np.isfinite(v) else np.nan for v in camera_rms], float)
    ch = np.array([v if v is not None and np.isfinite(v) else np.nan for v in chain_rms], float)
    w = 0.38
    edge = [RED if s in ("flagged", "dropped") else "none" for s in status]
    ax.bar(x - w / 2, np.nan_to_num(cam), w, color=NAVY, label="camera fit RMS", edgecolor=edge, linewidth=1.2)
    if np.any(np.isfinite(ch)):
        ax.bar(x + w / 2, np.nan_to_num(ch), w, color=SKY, label="through the robot RMS", edgecolor=edge,
               linewidth=1.2)
    allv = np.concatenate([cam, ch])
    allv = allv[np.isfinite(allv)]
    top = float(np.max(allv)) if len(allv) else 0.1
    typical = float(np.quantile(allv, 0.75)) if len(allv) else 0.1
    cap = max(4.0 * typical, (fail_px or 0.0) * 1.3, (warn_px or 0.0) * 1.3, 0.1)
    clipped = top > 1.05 * cap
    if clipped:  # one gross outlier must not flatten every other bar: cut the axis, print the value
        top = cap
        for xi, c, h in zip(x, cam, ch):
            for off, val in ((-w / 2, c), (w / 2, h)):
                if np.isfinite(val) and val > cap:
                    ax.text(xi + off, cap * 0.97, f"{val:.0f} px ↑" if val >= 10 else f"{val:.1f} px ↑",
                            ha="center", va="top", fontsize=7, color="white", fontweight="bold", rotation=90)
    for xi, s, c in zip(x, status, cam):
        if s == "dropped" and not np.isfinite(c):
            ax.text(xi, top * 0.04, "dropped", rotation=90, ha="center", va="bottom", fontsize=7, color=RED)
    if warn_px is not None:
        ax.axhline(warn_px, color=AMBER, lw=1.0, ls="--", label=f"QA warn {warn_px:g} px")
    if fail_px is not None and fail_px < top * 1.3:
        ax.axhline(fail_px, color=RED, lw=1.0, ls="--", label=f"QA fail {fail_px:g} px")
    ax.set_xticks(x)
    ax.set_xticklabels(ids, rotation=90 if n > 24 else 0, fontsize=7.5 if n > 24 else 8)
    ax.set_xlim(-0.7, n - 0.3)
    ax.set_xlabel("view id")
    ax.set_ylabel("RMS [px]")
    ax.grid(axis="x", visible=False)
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=4, borderaxespad=0.2)
    ax.set_ylim(0, top * (1.0 if clipped else 1.1))
    return _png(fig)


@_styled
def image_coverage(width: int, height: int, views: Sequence[tuple], counts: np.ndarray, *,
                   coverage_share: float) -> bytes:
    """Left: which parts of the image the corners reach (cell counts, each view's outline).
    Right: camera-fit residual vectors, magnified. ``views``: (id, points (N,2), residuals (N,2), flagged)."""
    aspect = height / max(width, 1)
    fig = _fig(8.6, 8.6 / 2 * aspect + 0.45)
    axs = fig.subplots(1, 2)
    ax = axs[0]
    ax.set_title(f"Corner coverage: {coverage_share:.0%} of the image")
    cmap = matplotlib.colors.LinearSegmentedColormap.from_list("cov", ["#ffffff", "#cfe0f1", "#5b8fc4", NAVY])
    masked = np.ma.masked_where(counts == 0, counts)
    ax.imshow(masked, extent=(0, width, height, 0), cmap=cmap, interpolation="nearest", aspect="equal",
              vmin=0, vmax=max(1, counts.max()), alpha=0.9)
    from scipy.spatial import ConvexHull, QhullError

    for vid, pts, _, flagged in views:
        if len(pts) >= 3:
            try:
                hull = ConvexHull(pts)
            except (QhullError, ValueError):
                continue
            ax.add_patch(Polygon(pts[hull.vertices], closed=True, fill=False, lw=0.7,
                                 ec=RED if flagged else MUTED, alpha=0.8))
    ax2 = axs[1]
    allr = np.concatenate([r for _, _, r, _ in views]) if views else np.zeros((0, 2))
    ref = float(np.quantile(np.linalg.norm(allr, axis=1), 0.9)) if len(allr) else 1.0
    gain = _nice_gain(0.045 * width / max(ref, 1e-9))
    ax2.set_title(f"Camera-fit residuals, magnified {gain:g}×")
    colors = matplotlib.colormaps["tab20"]
    for k, (vid, pts, r, flagged) in enumerate(views):
        if not len(pts):
            continue
        ax2.quiver(pts[:, 0], pts[:, 1], r[:, 0] * gain, r[:, 1] * gain, angles="xy", scale_units="xy", scale=1,
                   color=RED if flagged else colors(k % 20), width=0.0028, headwidth=3, headlength=3.5)
    # scale arrow: 1 px
    sx, sy = 0.06 * width, 0.94 * height
    one = _nice_gain(ref) if ref > 0 else 1.0
    ax2.annotate("", xy=(sx + one * gain, sy), xytext=(sx, sy),
                 arrowprops=dict(arrowstyle="-|>", color=INK, lw=1.2))
    ax2.text(sx, sy - 0.025 * height, f"{one:g} px", fontsize=7.5, color=INK)
    for a in (ax, ax2):
        a.add_patch(Rectangle((0, 0), width, height, fill=False, ec="#9aa5b4", lw=1.0))
        a.set_xlim(-0.02 * width, 1.02 * width)
        a.set_ylim(1.02 * height, -0.02 * height)
        a.set_aspect("equal")
        a.set_xlabel("u [px]")
        a.grid(False)
    ax.set_ylabel("v [px]")
    return _png(fig)


def _nice_gain(x: float) -> float:
    if not np.isfinite(x) or x <= 0:
        return 1.0
    e = 10 ** np.floor(np.log10(x))
    for m in (1, 2, 5, 10):
        if m * e >= x * 0.75:
            return float(m * e)
    return float(10 * e)


# ------------------------------------------------------------------------------ geometry
def _triad(ax, T, L, *, lw=1.2, alpha=1.0):
    o = T[:3, 3]
    for k, c in enumerate(("#d62728", "#2ca02c", "#1f77b4")):
        e = o + L * T[:3, k]
        ax.plot([o[0], e[0]], [o[1], e[1]], [o[2], e[2]], color=c, lw=lw, alpha=alpha)


def _frustum(ax, T, L, color, *, lw=0.9, alpha=0.9):
    corners = np.array([[-0.6, -0.45, 1.0], [0.6, -0.45, 1.0], [0.6, 0.45, 1.0], [-0.6, 0.45, 1.0]]) * L
    P = corners @ T[:3, :3].T + T[:3, 3]
    o = T[:3, 3]
    for p in P:
        ax.plot([o[0], p[0]], [o[1], p[1]], [o[2], p[2]], color=color, lw=lw, alpha=alpha)
    loop = np.vstack([P, P[:1]])
    ax.plot(loop[:, 0], loop[:, 1], loop[:, 2], color=color, lw=lw, alpha=alpha)


def _frustum_points(T, L) -> np.ndarray:
    """Outline of a camera pyramid as one polyline (M, 3) for 2-D projections."""
    c = np.array([[-0.6, -0.45, 1.0], [0.6, -0.45, 1.0], [0.6, 0.45, 1.0], [-0.6, 0.45, 1.0]]) * L
    P = c @ T[:3, :3].T + T[:3, 3]
    o = T[:3, 3]
    return np.array([o, P[0], P[1], o, P[2], P[3], o, P[0], P[3], P[2], P[1]])


def _board(ax, T, outline_board, color, *, alpha=0.35):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    P = outline_board @ T[:3, :3].T + T[:3, 3]
    ax.add_collection3d(Poly3DCollection([P], facecolor=color, edgecolor=color, alpha=alpha, linewidths=0.8))


@_styled
def poses_3d(*, T_base_cams: np.ndarray, T_base_ends: np.ndarray, T_base_boards: np.ndarray,
             board_outline: np.ndarray, flagged: Sequence[bool], mode: str) -> bytes:
    """Robot base, end poses, cameras and board(s) in the base frame (two viewpoints)."""
    import mpl_toolkits.mplot3d  # noqa: F401  (registers the 3d projection)

    pts = np.concatenate([T_base_cams[:, :3, 3], T_base_ends[:, :3, 3], T_base_boards[:, :3, 3], np.zeros((1, 3))])
    span = float(np.max(np.ptp(pts, axis=0))) or 1.0
    L = 0.07 * span
    fig = _fig(8.6, 4.0)
    ax = fig.add_subplot(1, 2, 1, projection="3d", proj_type="ortho")
    ax.set_title("Perspective", loc="left")
    _triad(ax, np.eye(4), 1.6 * L, lw=2.0)
    ax.text(0, 0, -0.6 * L, "base", fontsize=7.5, color=INK)
    for i in range(len(T_base_ends)):
        c = RED if flagged[i] else MUTED
        _triad(ax, T_base_ends[i], 0.6 * L, lw=0.8, alpha=0.7)
        if mode == "eye_in_hand":
            _frustum(ax, T_base_cams[i], 0.9 * L, RED if flagged[i] else NAVY)
        else:
            _board(ax, T_base_boards[i], board_outline, RED if flagged[i] else ORANGE, alpha=0.3)
        e, o = T_base_ends[i][:3, 3], (T_base_cams[i] if mode == "eye_in_hand" else T_base_boards[i])[:3, 3]
        ax.plot([e[0], o[0]], [e[1], o[1]], [e[2], o[2]], color=c, lw=0.5, alpha=0.6, ls=":")
    if mode == "eye_in_hand":
        _board(ax, T_base_boards[0], board_outline, ORANGE, alpha=0.55)
        ax.text(*T_base_boards[0][:3, 3], " board", fontsize=7.5, color=ORANGE)
    else:
        _frustum(ax, T_base_cams[0], 1.4 * L, NAVY, lw=1.4)
        ax.text(*T_base_cams[0][:3, 3], " camera", fontsize=7.5, color=NAVY)
    lo, hi = pts.min(axis=0) - L, pts.max(axis=0) + L
    c, r = (lo + hi) / 2, float(np.max(hi - lo)) / 2
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=24, azim=-58)
    ax.set_xlabel("x [m]", labelpad=-2)
    ax.set_ylabel("y [m]", labelpad=-2)
    ax.set_zlabel("z [m]", labelpad=-2)
    ax.tick_params(labelsize=6.5, pad=0)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.pane.set_facecolor("#f6f8fb")
        axis.pane.set_edgecolor(GRID)
    # top view, true 2-D
    a2 = fig.add_subplot(1, 2, 2)
    a2.set_title("Top view (base x–y)")
    a2.plot([0, 1.6 * L], [0, 0], color="#d62728", lw=2.0)
    a2.plot([0, 0], [0, 1.6 * L], color="#2ca02c", lw=2.0)
    a2.text(0.15 * L, -0.5 * L, "base", fontsize=7.5, color=INK)
    for i in range(len(T_base_ends)):
        e = T_base_ends[i][:3, 3]
        a2.plot(e[0], e[1], "o", ms=3, color=RED if flagged[i] else MUTED, alpha=0.8)
        if mode == "eye_in_hand":
            P = _frustum_points(T_base_cams[i], 0.9 * L)
            a2.plot(P[:, 0], P[:, 1], color=RED if flagged[i] else NAVY, lw=0.8, alpha=0.9)
        else:
            B = board_outline @ T_base_boards[i][:3, :3].T + T_base_boards[i][:3, 3]
            a2.fill(B[:, 0], B[:, 1], color=RED if flagged[i] else ORANGE, alpha=0.25, lw=0.8)
    if mode == "eye_in_hand":
        B = board_outline @ T_base_boards[0][:3, :3].T + T_base_boards[0][:3, 3]
        a2.fill(B[:, 0], B[:, 1], color=ORANGE, alpha=0.5, lw=0.8)
    else:
        P = _frustum_points(T_base_cams[0], 1.4 * L)
        a2.plot(P[:, 0], P[:, 1], color=NAVY, lw=1.3)
        a2.text(T_base_cams[0][0, 3], T_base_cams[0][1, 3], " camera", fontsize=7.5, color=NAVY)
    a2.plot([], [], "o", ms=3, color=MUTED, label="robot end (flange)")
    a2.plot([], [], color=NAVY, label="camera")
    a2.fill([], [], color=ORANGE, alpha=0.4, label="board")
    a2.legend(loc="best", fontsize=7)
    a2.set_aspect("equal", adjustable="datalim")
    a2.set_xlabel("x [m]")
    a2.set_ylabel("y [m]")
    return _png(fig)


@_styled
def rotation_coverage(rotvecs: np.ndarray, *, frame: str, warn_deg: Optional[float],
                      fail_deg: Optional[float]) -> bytes:
    """Axes of the pairwise robot rotations on an equal-area disk (hemisphere, sign folded) and their angles."""
    rv = np.asarray(rotvecs, float).reshape(-1, 3)
    ang = np.linalg.norm(rv, axis=1)
    fig = _fig(8.6, 3.5)
    gs = fig.add_gridspec(1, 2, width_ratios=[1.0, 1.35])
    ax = fig.add_subplot(gs[0])
    ax.set_title(f"Rotation axes ({frame} frame)")
    keep = ang > np.radians(2.0)
    a = rv[keep] / ang[keep, None] if keep.any() else np.zeros((0, 3))
    a = np.where(a[:, 2:3] < 0, -a, a)  # fold to the upper hemisphere (axis and -axis are one line)
    # Lambert azimuthal equal-area projection of the upper hemisphere onto the unit disk
    rr = np.sqrt(np.clip(1.0 - a[:, 2], 0.0, None))
    phi = np.arctan2(a[:, 1], a[:, 0])
    x, y = rr * np.cos(phi), rr * np.sin(phi)
    t = np.linspace(0, 2 * np.pi, 200)
    for r0, lab in ((np.sqrt(1 - np.cos(np.radians(30))), "30°"), (np.sqrt(1 - np.cos(np.radians(60))), "60°"),
                    (1.0, "90°")):
        ax.plot(r0 * np.cos(t), r0 * np.sin(t), color=GRID if r0 < 1 else "#b9c1cc", lw=0.8)
        ax.text(r0 * np.cos(np.radians(75)), r0 * np.sin(np.radians(75)), lab, fontsize=6.5, color=MUTED)
    ax.plot([-1, 1], [0, 0], color=GRID, lw=0.8)
    ax.plot([0, 0], [-1, 1], color=GRID, lw=0.8)
    sc = ax.scatter(x, y, c=np.degrees(ang[keep]), cmap="viridis", s=12, vmin=0,
                    vmax=max(90.0, float(np.degrees(ang.max())) if len(ang) else 90.0), edgecolor="none")
    ax.text(1.04, 0, "+x", fontsize=7.5, va="center")
    ax.text(0, 1.05, "+y", fontsize=7.5, ha="center")
    ax.text(0.03, 0.03, "z", fontsize=7.5, color=MUTED)
    ax.text(0.0, -1.13, "rings: tilt of the axis from +z", fontsize=6.8, color=MUTED, ha="center")
    ax.set_xlim(-1.15, 1.15)
    ax.set_ylim(-1.15, 1.15)
    ax.set_aspect("equal")
    ax.axis("off")
    cb = fig.colorbar(sc, ax=ax, shrink=0.75, pad=0.02)
    cb.set_label("rotation [deg]", fontsize=7.5)
    cb.ax.tick_params(labelsize=7)
    ax2 = fig.add_subplot(gs[1])
    ax2.set_title(f"Rotation between view pairs ({len(ang)} pairs)")
    if len(ang):
        ax2.hist(np.degrees(ang), bins=np.linspace(0, max(180.0, np.degrees(ang.max())), 37), color=NAVY,
                 alpha=0.8, edgecolor="white", linewidth=0.4)
    if fail_deg is not None:
        ax2.axvline(fail_deg, color=RED, ls="--", lw=1.0, label=f"QA fail < {fail_deg:g}° (largest)")
    if warn_deg is not None:
        ax2.axvline(warn_deg, color=AMBER, ls="--", lw=1.0, label=f"QA warn < {warn_deg:g}° (largest)")
    ax2.set_xlabel("relative rotation [deg]")
    ax2.set_ylabel("view pairs")
    ax2.set_xlim(0, 180)
    ax2.legend(loc="upper right")
    return _png(fig)


@_styled
def translation_uncertainty(cov_t_mm2: Optional[np.ndarray], methods: Sequence[tuple], *, frame: str,
                            x_name: str) -> bytes:
    """1- and 2-sigma ellipses of the translation (three planes of ``frame``), with the closed-form methods
    as points relative to the result. ``methods``: (name, offset_mm (3,))."""
    fig = _fig(8.6, 3.0)
    axs = fig.subplots(1, 3)
    planes = [(0, 1), (0, 2), (1, 2)]
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
    for k, (i, j) in enumerate(planes):
        ax = axs[k]
        ax.set_title(f"{lab[i]}–{lab[j]} plane")
        if cov_t_mm2 is not None:
            C = cov_t_mm2[np.ix_([i, j], [i, j])]
            for ks, ls, a in ((1.0, "-", 0.22), (2.0, "--", 0.08)):
                E = ellipse_points(C, k_sigma=ks)
                ax.fill(E[:, 0], E[:, 1], color=NAVY, alpha=a, lw=0)
                ax.plot(E[:, 0], E[:, 1], color=NAVY, lw=1.0, ls=ls, label=f"{ks:g} σ" if k == 0 else None)
        ax.plot([0], [0], marker="+", color=INK, ms=9, mew=1.5, ls="none", label="result" if k == 0 else None)
        for n, (name, o) in enumerate(methods):
            px, py = o[i], o[j]
            outside = max(abs(px), abs(py)) > lim
            if outside:  # pin to the border along its direction, hollow marker
                f = 0.97 * lim / max(abs(px), abs(py))
                px, py = px * f, py * f
            ax.plot(px, py, marker=markers[n % len(markers)], ms=4.5, ls="none", color=f"C{n % 10}",
                    mfc="none" if outside else f"C{n % 10}", label=name if k == 0 else None, alpha=0.9)
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.set_xlabel(f"Δ{lab[i]} [mm]")
        ax.set_ylabel(f"Δ{lab[j]} [mm]")
    handles, labels = axs[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right center", fontsize=7.5)
    note = f"; hollow: {n_out} beyond the range, at the border" if n_out else ""
    fig.suptitle(f"Translation of {x_name} ({frame} frame), offsets from the result{note}", fontsize=9.5,
                 fontweight="bold", x=0.01, ha="left", color=INK)
    return _png(fig)
