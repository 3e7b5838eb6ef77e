"""Single markers and AprilGrids through bench_foreign.py's independent renderer: corner errors against the truth.

bench_foreign.py renders chessboard sessions with its own lens model and board renderer (no handeye code),
through a camera's tone curve (gamma 1.8-2.4), shading, vignetting, blur, noise and JPEG. Here its board is
replaced by one AprilTag 36h11 (id 0) of 40-120 mm on one to two cells of paper, over its textured background,
and each view is detected by ``handeye.detect.markers.detect_markers`` twice: as it is, and with the cells' shift
(``handeye.detect.cell_shift``) left out. Printed per variant: views, the RMS and worst of each view's worst
corner, the mean error along the line from the marker's centre through each corner (> 0: outwards) and its
range over views, and the views with a corner over 0.5 px and 2 px off. ``--target aprilgrid``: Kalibr
AprilGrids as Kalibr prints them (6x6, 5x4, 4x3, 6x4 tags of 20-60 mm, spacing 0.3) instead, detected once
(their corners are X junctions, no shift); printed: the share of corners found, the corner error RMS (median
over views) and at most, and the mean error outwards from each tag's centre. Asserts nothing.

    python benchmarks/bench_foreign_markers.py [--target marker|aprilgrid] [--seeds 10] [--views 4]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_foreign as F  # noqa: E402

from handeye.detect import detect_gray  # noqa: E402
from handeye.detect import markers as M  # noqa: E402
from handeye.detect.cell_shift import marker_cells  # noqa: E402
from handeye.targets import AprilGridSpec, MarkerSpec  # noqa: E402

SPEC_DICT, SPEC_ID = "DICT_APRILTAG_36h11", 0


def _print_albedo(renderer, T_cam_board, shade, bounds, ink_of):
    """bench_foreign's ``coverage_and_albedo`` for a print of paper over ``bounds`` (x0, x1, y0, y1, metres in the
    board frame) whose ink is where ``ink_of(bx, by)`` is true."""
    R, t = T_cam_board[:3, :3], T_cam_board[:3, 3]
    o = -R.T @ t
    s, W, H = renderer.s, renderer.W, renderer.H
    cov, alb = np.zeros((H, W)), np.zeros((H, W))
    step = 32 * s
    for r0 in range(0, H * s, step):
        x = renderer.rx[r0 : r0 + step].astype(np.float64)
        y = renderer.ry[r0 : r0 + step].astype(np.float64)
        dx, dy, dz = (R[0, j] * x + R[1, j] * y + R[2, j] for j in range(3))  # R^T (x, y, 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = -o[2] / dz
        bx, by = o[0] + lam * dx, o[1] + lam * dy
        hit = renderer.ok[r0 : r0 + step] & (lam > 0)
        hit &= (bx > bounds[0]) & (bx < bounds[1]) & (by > bounds[2]) & (by < bounds[3])
        a = np.where(hit, np.where(ink_of(bx, by), 0.06, 0.88) * (1 + shade[0] * bx + shade[1] * by), 0.0)
        k = a.shape[0] // s
        cov[r0 // s : r0 // s + k] = hit.reshape(k, s, W, s).mean(axis=(1, 3))
        alb[r0 // s : r0 // s + k] = a.reshape(k, s, W, s).mean(axis=(1, 3))
    return cov, alb


def _tag_ink(cells: np.ndarray, ox: float, oy: float, side: float, bx: np.ndarray, by: np.ndarray) -> np.ndarray:
    """Where the tag of ``cells`` with its top-left corner at (ox, oy) and side ``side`` inks (bx, by); else NaN."""
    n = len(cells)
    ci, cj = np.floor((bx - ox) / (side / n)), np.floor((by - oy) / (side / n))
    inside = (ci >= 0) & (ci < n) & (cj >= 0) & (cj < n)
    ink = np.full(bx.shape, np.nan)
    ink[inside] = cells[cj[inside].astype(int), ci[inside].astype(int)]
    return ink


def marker_albedo(renderer, T_cam_board, shade):
    """One marker of side ``square_m`` on ``margin_m`` of paper."""
    S, m = renderer.cfg["square_m"], renderer.cfg["margin_m"]
    cells = marker_cells(SPEC_DICT, SPEC_ID)
    return _print_albedo(
        renderer, T_cam_board, shade, (-m, S + m, -m, S + m), lambda bx, by: _tag_ink(cells, 0, 0, S, bx, by) == 1
    )


def grid_albedo(renderer, T_cam_board, shade):
    """The AprilGrid ``cfg["grid"]`` on ``margin_m`` of paper: its tags and the gap squares at their corners.

    Each tag as Kalibr prints it: two black border cells and the code as AprilTag lays it out (OpenCV's marker
    turned by a half turn).
    """
    spec: AprilGridSpec = renderer.cfg["grid"]
    S, P, g, m = spec.size_m, spec.pitch_m, spec.spacing * spec.size_m, renderer.cfg["margin_m"]
    cells = [
        np.pad(marker_cells(spec.dictionary, int(spec.first_id + k))[::-1, ::-1], 1, constant_values=True)
        for k in range(spec.n_tags)
    ]

    def ink(bx, by):
        cx, cy = np.floor((bx + g) / P), np.floor((by + g) / P)
        out = (bx >= cx * P - g) & (bx < cx * P) & (cx >= 0) & (cx <= spec.cols)
        out &= (by >= cy * P - g) & (by < cy * P) & (cy >= 0) & (cy <= spec.rows)
        for k, (ox, oy, _) in enumerate(spec.tag_origins()):
            tag = _tag_ink(cells[k], ox, oy, S, bx, by)
            out = np.where(np.isnan(tag), out, tag == 1)
        return out

    return _print_albedo(renderer, T_cam_board, shade, (-g - m, spec.cols * P + m, -g - m, spec.rows * P + m), ink)


def _jpeg_grey(renderer, cfg, rng, T) -> np.ndarray:
    ok, buf = cv2.imencode(".jpg", F.render_view(renderer, cfg, rng, T), [cv2.IMWRITE_JPEG_QUALITY, cfg["jpeg"]])
    return cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)


def aprilgrids(seeds: int, views: int) -> None:
    F.Renderer.coverage_and_albedo = grid_albedo
    found, total, rms, worst, outwards = 0, 0, [], 0.0, []
    for seed in range(seeds):
        cfg, rng = F.session_settings(seed)
        cols, rows = [(6, 6), (5, 4), (4, 3), (6, 4)][seed % 4]
        spec = AprilGridSpec(cols, rows, round(float(rng.uniform(0.02, 0.06)), 3), 0.3)
        P, W, fx = spec.pitch_m, cfg["size"][0], cfg["K"][0][0]
        cfg.update(grid=spec, board=(cols + 1, rows + 1), square_m=P, margin_m=0.3 * spec.size_m)
        cfg["d_range"] = (max(0.2, fx * (cols + 1) * P / (0.85 * W)), max(0.3, fx * (cols + 1) * P / (0.35 * W)))
        renderer, K, dist = F.Renderer(cfg), np.array(cfg["K"]), np.array(cfg["dist"])
        for _ in range(views):
            T = F.sample_view(cfg, rng, "full")
            out = detect_gray(_jpeg_grey(renderer, cfg, rng, T), spec)
            total += spec.n_corners
            if isinstance(out, str):
                continue
            ids, pts = out
            true = F.project(K, dist, T, spec.object_points())[ids]
            centre = np.stack([true[ids // 4 == t].mean(axis=0) for t in ids // 4])
            radial = (true - centre) / np.linalg.norm(true - centre, axis=1, keepdims=True)
            e = np.linalg.norm(pts - true, axis=1)
            found, worst = found + len(ids), max(worst, float(e.max()))
            rms.append(float(np.sqrt(np.mean(e**2))))
            outwards.append(float(np.mean(np.sum((pts - true) * radial, axis=1))))
    print(
        f"AprilGrid: {found} of {total} corners found ({found / total:.0%}); corner error RMS median "
        f"{np.median(rms):.3f} px ({min(rms):.3f}-{max(rms):.3f} over views), at most {worst:.3f}; outwards "
        f"{np.mean(outwards):+.3f} px ({min(outwards):+.3f}..{max(outwards):+.3f})"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10, help="cameras (bench_foreign's session settings of seeds 0..)")
    ap.add_argument("--views", type=int, default=4, help="views per camera")
    ap.add_argument("--target", choices=("marker", "aprilgrid"), default="marker")
    a = ap.parse_args(argv)
    if a.target == "aprilgrid":
        aprilgrids(a.seeds, a.views)
        return 0
    F.Renderer.coverage_and_albedo = marker_albedo
    with_shift = M.ink_shift_px
    rows: dict[str, list] = {"as it is": [], "without the cells' shift": []}
    for seed in range(a.seeds):
        cfg, rng = F.session_settings(seed)
        S = round(float(rng.uniform(0.04, 0.12)), 3)
        W, fx = cfg["size"][0], cfg["K"][0][0]
        cfg.update(board=(2, 2), square_m=S, margin_m=S / 8 * rng.uniform(1.0, 2.0))  # the marker's corners
        cfg["d_range"] = (max(0.15, fx * 3 * S / (0.8 * W)), max(0.2, fx * S / (0.12 * W)))
        renderer, spec = F.Renderer(cfg), MarkerSpec(S)
        K, dist = np.array(cfg["K"]), np.array(cfg["dist"])
        for _ in range(a.views):
            T = F.sample_view(cfg, rng, "full")
            gray = _jpeg_grey(renderer, cfg, rng, T)
            truth = F.project(K, dist, T, np.array([[0, 0, 0], [S, 0, 0], [S, S, 0], [0, S, 0.0]]))
            for name, r in rows.items():
                M.ink_shift_px = with_shift if name == "as it is" else (lambda *_a, **_k: None)
                out = M.detect_markers(gray, spec)
                if isinstance(out, str):
                    r.append((np.nan, np.nan))
                    continue
                ids, pts = out
                true = truth[ids]
                radial = (true - true.mean(axis=0)) / np.linalg.norm(true - true.mean(axis=0), axis=1, keepdims=True)
                r.append((np.linalg.norm(pts - true, axis=1).max(), np.mean(np.sum((pts - true) * radial, axis=1))))
    M.ink_shift_px = with_shift
    for name, r in rows.items():
        e = np.array(r)
        found = e[np.isfinite(e[:, 0])]
        print(
            f"{name}: {len(found)} of {len(e)} views found; worst corner per view RMS "
            f"{np.sqrt(np.mean(found[:, 0] ** 2)):.3f} px, at most {found[:, 0].max():.3f}; outwards "
            f"{found[:, 1].mean():+.3f} px ({found[:, 1].min():+.3f}..{found[:, 1].max():+.3f}); views with a corner "
            f"over 0.5 px off {int((found[:, 0] > 0.5).sum())}, over 2 px {int((found[:, 0] > 2).sum())}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
