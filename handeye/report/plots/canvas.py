"""The report figures' style and drawing helpers (an Agg canvas, palette PNGs, one artist per kind of line).

Drawing is kept light, because it is most of a report's cost: an Agg canvas without pyplot state, fixed
margins instead of a layout engine, one collection per kind of line instead of one artist per line,
2-D projections instead of mplot3d, and 8-bit palette PNGs. matplotlib is imported when the figures'
style is entered (:func:`style`), before the figures are drawn.
"""

from __future__ import annotations

import contextlib
import io

import numpy as np

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
    """The report's matplotlib style, for a whole batch of figures (one rc context, not one per call).

    It also imports the modules every figure draws with: :func:`handeye.report.figures.draw_figures` forks
    its drawing process inside this context, and the child inherits them instead of importing them again.
    """
    import matplotlib
    import matplotlib.backends.backend_agg  # noqa: F401 - imported before the fork, see above
    import matplotlib.figure  # noqa: F401
    import PIL.Image  # noqa: F401

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
