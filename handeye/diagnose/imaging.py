"""Image-level findings: blurred, overexposed and corners_bunched.

Blur and exposure come from the measures detection took on the image it decoded
(:mod:`handeye.detect.quality`); corners_bunched from the coverage of the image by all views' corners.
"""

from __future__ import annotations

import numpy as np

from ..detect.quality import view_blur, view_exposure


def coverage(points: np.ndarray, width: int, height: int, *, nx: int = 8, ny: int = 6) -> dict:
    """How the corners of all views cover the image.

    Share of an nx x ny grid of cells that hold at least one corner, share of the border cells, and
    the occupancy grid (rows top to bottom).
    """
    pts = np.asarray(points, float).reshape(-1, 2)
    occ = np.zeros((ny, nx), bool)
    if len(pts):
        cx = np.clip((pts[:, 0] / max(width, 1) * nx).astype(int), 0, nx - 1)
        cy = np.clip((pts[:, 1] / max(height, 1) * ny).astype(int), 0, ny - 1)
        occ[cy, cx] = True
    border = occ.copy()
    border[1:-1, 1:-1] = False
    n_border = 2 * nx + 2 * ny - 4
    return {
        "cell_share": float(occ.mean()),
        "border_share": float(border.sum()) / n_border,
        "grid": occ.astype(int).tolist(),
        "grid_size": [nx, ny],
    }


def uncovered_regions(grid: np.ndarray) -> list[str]:
    """Names of the image regions (corners and edges of a 3x3 split) that hold no corner at all."""
    g = np.asarray(grid, bool)
    ny, nx = g.shape
    ys = np.array_split(np.arange(ny), 3)
    xs = np.array_split(np.arange(nx), 3)
    names = [["top-left", "top", "top-right"], ["left", "centre", "right"], ["bottom-left", "bottom", "bottom-right"]]
    out = []
    for r in range(3):
        for c in range(3):
            if not g[np.ix_(ys[r], xs[c])].any():
                out.append(names[r][c])
    return out


# ------------------------------------------------------------------------------ findings on the images
def image_metrics(run, *, max_views: int = 200) -> dict:
    """Per used view: blur and exposure.

    Taken from the detection record when detection measured them on the image it decoded; otherwise
    measured here (unreadable images are skipped).
    """
    from ..detect import read_gray
    from ..errors import HandeyeError

    s = run.session
    obj = s.target.object_points()
    out = {}
    for vid, det in list((run.detections or {}).items())[:max_views]:
        blur, exposure = getattr(det, "blur", None), getattr(det, "exposure", None)
        if blur is None or exposure is None:
            try:
                gray = read_gray(s.view(vid).image_path)
            except (HandeyeError, KeyError, OSError):
                continue
            ids = run.board_poses[vid].corner_ids if vid in (run.board_poses or {}) else det.corner_ids
            blur = view_blur(gray, det.image_points, ids, obj, s.target.square_m, charuco=s.target.kind == "charuco")
            exposure = view_exposure(gray, det.image_points)
        out[vid] = dict(blur, **exposure)
    return out


def image_findings(metrics: dict) -> list:
    """Blurred (edge width) and overexposed (saturation, washed-out blacks) views."""
    from .findings import Finding
    from .thresholds import thresholds

    t = thresholds().images
    out: list[Finding] = []
    if not metrics:
        return out
    blur = {v: m for v, m in metrics.items() if np.isfinite(m.get("blur_sigma_px", np.nan))}
    if blur:
        med = float(np.median([m["blur_sigma_px"] for m in blur.values()]))
        bad = []
        for v, m in blur.items():
            b, sq = m["blur_sigma_px"], m.get("square_px", np.inf)
            if (b > t.blur_warn_px and b > t.blur_warn_square_share * sq) or (
                b > t.blur_outlier_px and b > t.blur_outlier_ratio * max(med, t.sharp_blur_floor_px)
            ):
                bad.append(v)
        if bad:
            ev = "; ".join(
                f"view {v}: edges blurred by {blur[v]['blur_sigma_px']:.1f} px (squares "
                f"{blur[v].get('square_px', float('nan')):.0f} px)"
                for v in bad[:12]
            )
            ev += f"; median of all views {med:.2f} px (a sharp image: < 0.5 px)"
            out.append(
                Finding(
                    "blurred",
                    "warn",
                    f"Blurred images: {len(bad)} view(s)",
                    ev,
                    "focus the lens at the working distance, use a shorter exposure (more light) "
                    "and let the robot settle before each capture",
                    view_ids=tuple(bad),
                    details={v: {"blur_sigma_px": blur[v]["blur_sigma_px"]} for v in bad},
                )
            )
    over_w = [
        v
        for v, m in metrics.items()
        if m.get("saturated_share", 0) > t.overexposed_warn_share or m.get("p5", 0) > t.washed_out_black_grey
    ]
    over_i = [
        v for v, m in metrics.items() if v not in over_w and m.get("saturated_share", 0) > t.overexposed_info_share
    ]
    if over_w:
        ev = "; ".join(
            f"view {v}: {100 * metrics[v]['saturated_share']:.0f}% of the board saturated, black squares "
            f"at grey {metrics[v]['p5']:.0f}"
            for v in over_w[:12]
        )
        out.append(
            Finding(
                "overexposed",
                "warn",
                f"Overexposed images: {len(over_w)} view(s)",
                ev,
                "reduce exposure or gain (or light) until the white squares are just below "
                "saturation; clipped, blooming whites shift the corners",
                view_ids=tuple(over_w),
            )
        )
    elif over_i:
        ev = "; ".join(
            f"view {v}: {100 * metrics[v]['saturated_share']:.0f}% of the board saturated" for v in over_i[:12]
        )
        out.append(
            Finding(
                "overexposed",
                "info",
                f"White squares clipped in {len(over_i)} view(s)",
                ev,
                "a slightly shorter exposure would keep the whites below saturation",
                view_ids=tuple(over_i),
            )
        )
    return out


def coverage_findings(run) -> list:
    """corners_bunched: the corners of all views cover little of the image."""
    from .findings import Finding
    from .thresholds import thresholds

    dets = list((run.detections or {}).values())
    if not dets:
        return []
    W, H = dets[0].image_size
    cov = coverage(np.concatenate([d.image_points for d in dets]), W, H)
    if cov["cell_share"] >= thresholds().images.coverage_warn_share:
        return []
    empty = uncovered_regions(np.array(cov["grid"]))
    given = run.session.intrinsics is not None and run.session.intrinsics_prior in ("fixed", "prior")
    why = (
        "the hand-eye result relies on image regions the board never reached"
        if given
        else "the lens distortion is only measured where the corners are; elsewhere it is extrapolated"
    )
    return [
        Finding(
            "corners_bunched",
            "warn",
            "The corners cover only part of the image",
            f"corners of all {len(dets)} views fall in {100 * cov['cell_share']:.0f}% of an 8x6 grid over the "
            f"image ({100 * cov['border_share']:.0f}% of the border cells); no corner in: "
            f"{', '.join(empty) if empty else '-'}; {why}",
            "add views with the board near the image's edges and corners (move or tilt so the board "
            "fills those regions)",
            details=cov,
        )
    ]
