"""The residual figures: residual histogram, residual per view, image coverage with residual vectors."""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from .canvas import (
    AMBER,
    INK,
    MUTED,
    NAVY,
    ORANGE,
    RED,
    SKY,
    TEAL,
    WIDTH_IN,
    _bars,
    _few_ticks,
    _fig,
    _hull,
    _lines,
    _no_grid,
    _png,
)


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
    edge = [RED if s == "dropped" else "none" for s in status]
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
            for off, val, colour in ((-w / 2, c, NAVY), (w / 2, h, SKY)):
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
                        zorder=5,  # over the QA lines, on a patch of its bar's colour: a line never crosses it
                        bbox={"facecolor": colour, "edgecolor": "none", "pad": 0.6},
                    )
    for xi, s, c in zip(x, status, cam, strict=False):
        if s == "dropped" and not np.isfinite(c):
            ax.text(xi, top * 0.04, "dropped", rotation=90, ha="center", va="bottom", fontsize=7, color=RED)
    shown = top * (1.0 if clipped else 1.1)  # the axis' top: a limit above it is neither drawn nor in the legend
    if warn_px is not None and warn_px <= shown:
        ax.axhline(warn_px, color=AMBER, lw=1.0, ls="--", label=f"QA warn {warn_px:g} px")
    if fail_px is not None and fail_px <= shown:
        ax.axhline(fail_px, color=RED, lw=1.0, ls="--", label=f"QA fail {fail_px:g} px")
    ax.set_xticks(x)
    ax.set_xticklabels(ids, rotation=90 if n > 24 else 0, fontsize=7.5 if n > 24 else 8)
    ax.set_xlim(-0.7, n - 0.3)
    ax.set_xlabel("view id")
    ax.set_ylabel("RMS [px]")
    ax.xaxis.grid(False)
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=4, borderaxespad=0.2)
    ax.set_ylim(0, shown)
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
