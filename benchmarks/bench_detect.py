"""Detection on a rendered 1280x720 vendor session: time per image by part, the whole session, corner
accuracy against the ground truth, and the cornerSubPix stopping rule of configs/detection.yaml.

Usage: python benchmarks/bench_detect.py [--views 20] [--rounds 7] [--session DIR] [--real DIR ...]
                                         [--shared DIR | --no-shared] [--big W H] [--supersample 4 8]
       python benchmarks/bench_detect.py --wrong-size 54   (only the wrong-board-size sweep: N rendered
       20-view sessions whose config.yaml states another size; refused naming the true size, and the time)
Then: the refusal of a wrong board size (the session's images under a config.yaml that states 9x6 inner
corners for the 11x8 board) through detect_views and through the whole calibration
(handeye.workflow.calibrate_session without the reports), with the message it gives; the corner error
and time on rendered 1280x720 views of a board of few large squares (5x4 inner corners of 60 mm, the
low-texture case); an 8000x6000 noise image (--big) alone and in a session of three views of that size
(the bounded detection: searched on a copy reduced to configs/detection.yaml search_max_megapixels);
a view without the board under a 1 ms time budget (dropped as timed out). On the real sets of
../shared/data (--shared): the chessboard sets' corners against findChessboardCornersSB (EXHAUSTIVE |
ACCURACY) where both detect, and the geometric check's worst corner (px and share of its limit) on every
set, ChArUco and circle grid included (the figures behind grid_check_max_px), and for the corners over
1 px from SB which of the two lies nearer its neighbours' homography, and cv2.calibrateCamera's RMS with
each detector's corners (which corners a camera model explains better); both detectors against a third
estimate that is neither's method, the intersection of each inner corner's two edge lines fitted to the
image (--crops DIR also writes each corner over 1 px from SB enlarged with both marks); the ViSP views
rendered again from their solvePnP poses, both detectors and the edge-line intersection against that truth
(which one is off where they disagree). The
rendered and real chessboard figures are printed for both refinement stages and for the cornerSubPix
stage alone (time in the same process, so the ratio holds under any load).
--real (e.g. ../shared/data/ur3-eyetohand-cam1, a 9x7 chessboard) also compares the cornerSubPix
stopping rules on real images: how far the shipped rule leaves the corners from the 50 / 1e-4 rule.
Renders a session (handeye.sim.vendor.write_vendor_session, view 5 hidden so one view takes the
not-found path) unless --session names one with ground_truth.json. Wall-clock figures depend on
machine load; CPU time (all threads) is printed too, the minimum over rounds. The JPEG lines compare
read_gray (decoded straight to luma) with decoding the colours and converting them; the colour path
costs 3 ms in a process whose allocator already holds large blocks and 5.6 ms in a fresh one (the
2.7 MB colour buffer is then mapped and faulted in anew each time).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from handeye.camera import Intrinsics, pixels_from_board_points
from handeye.detect import Detection, DetectionFailure, detect_gray, detect_image, detect_views, read_gray
from handeye.detect.chessboard import board_squares, refine_corners, subpix_windows
from handeye.detect.geometry import check_corners
from handeye.detect.options import default_options
from handeye.detect.quality import sharpness, thumbnail_jpeg, view_blur, view_exposure
from handeye.session import load_session
from handeye.targets import ChessboardSpec


@contextlib.contextmanager
def _one_stage():
    """The chessboard corners as refined before the second stage: cornerSubPix alone on the unsmoothed image
    (for the time and accuracy of detection without the symmetry fit, in the same process and load)."""
    import handeye.detect.chessboard as chessboard

    two = chessboard.final_corners
    chessboard.final_corners = lambda gray, bxy, start, win, o, dropped=None: refine_corners(gray, start, win, o)
    try:
        yield
    finally:
        chessboard.final_corners = two


def _best(f, items, rounds):
    """(wall ms, CPU ms) per item, the minimum over rounds."""
    wall, cpu = [], []
    for _ in range(rounds):
        t0, c0 = time.perf_counter(), time.process_time()
        for it in items:
            f(*it)
        wall.append((time.perf_counter() - t0) / len(items) * 1e3)
        cpu.append((time.process_time() - c0) / len(items) * 1e3)
    return min(wall), min(cpu)


def _truth(folder: Path, session):
    """view id -> true pixels of every corner, from ground_truth.json."""
    gt = json.loads((folder / "ground_truth.json").read_text())
    i, d = gt["intrinsics"], gt["intrinsics"]["dist"]
    K = np.array([[i["fx"], 0, i["cx"]], [0, i["fy"], i["cy"]], [0, 0, 1]])
    intr = Intrinsics.from_K(K, np.array([d["k1"], d["k2"], d["p1"], d["p2"], d["k3"]]), *i["image_size"])
    obj = session.target.object_points()
    out = {}
    for vid, v in gt["views"].items():
        if not v.get("hidden"):
            out[vid] = pixels_from_board_points(np.array(v["T_cam_board_true"]), obj, intr)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--session", type=Path, default=None)
    ap.add_argument("--real", type=Path, nargs="*", default=[], help="folders of real 9x7 chessboard images")
    ap.add_argument("--real-board", type=int, nargs=2, default=(9, 7))
    ap.add_argument(
        "--shared",
        type=Path,
        default=Path(__file__).resolve().parents[2] / "shared" / "data",
        help="folder of the real datasets (the chessboard sets are compared with the accurate SB search)",
    )
    ap.add_argument("--no-shared", action="store_true", help="skip the real datasets")
    ap.add_argument(
        "--crops",
        type=Path,
        default=None,
        metavar="DIR",
        help="write each real corner over 1 px from SB enlarged 8x with both detectors' marks "
        "(ours red, SB's green) to DIR, e.g. reports/sb-crops",
    )
    ap.add_argument("--big", type=int, nargs=2, default=(8000, 6000), help="size of the noise image, px")
    ap.add_argument(
        "--supersample",
        type=int,
        nargs="+",
        default=[4],
        help="samples per pixel (per axis) of the low-texture renders, e.g. 4 8",
    )
    ap.add_argument(
        "--wrong-size",
        type=int,
        default=0,
        metavar="N",
        help="only: N rendered sessions stated with a wrong board size (refusal, size named, time)",
    )
    args = ap.parse_args()
    if args.wrong_size:
        with tempfile.TemporaryDirectory() as tmp:
            _wrong_size_sweep(args.wrong_size, Path(tmp))
        return
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.session
        if folder is None:
            from handeye.sim.vendor import write_vendor_session

            folder = write_vendor_session(Path(tmp) / "s", n_views=args.views, seed=0, hidden_views=("5",))
        s = load_session(folder)
        views = list(s.views)
        items = [(v.view_id, v.image_path) for v in views]
        target, obj, o = s.target, s.target.object_points(), default_options()
        grays = {v.view_id: read_gray(v.image_path) for v in views}
        found = {vid: detect_gray(g, target) for vid, g in grays.items()}
        board = [(vid, grays[vid], found[vid]) for vid in grays if not isinstance(found[vid], str)]
        print(
            f"session {folder}: {len(views)} images {grays[views[0].view_id].shape[1]}x"
            f"{grays[views[0].view_id].shape[0]}, target found in {len(board)}"
        )

        def colour_then_grey(vid, path):
            data = np.fromfile(str(path), np.uint8)
            cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2GRAY)

        rows = [
            ("decode: read_gray", lambda vid, p: read_gray(p), items),
            ("decode: colour + cvtColor", colour_then_grey, items),
            ("detect_gray (views with the board)", lambda vid, g, d: detect_gray(g, target), board),
            ("sharpness", lambda vid, g, d: sharpness(g, d[1]), board),
            ("view_blur", lambda vid, g, d: view_blur(g, d[1], d[0], obj, target.square_m), board),
            ("view_exposure", lambda vid, g, d: view_exposure(g, d[1]), board),
            ("thumbnail_jpeg", lambda vid, g, d: thumbnail_jpeg(g), board),
            ("detect_image (all views)", lambda vid, p: detect_image(vid, p, target), items),
        ]
        for name, f, its in rows:
            w, c = _best(f, its, args.rounds)
            print(f"  {name:38s} {w:7.2f} ms wall  {c:7.2f} ms CPU per image")
        with _one_stage():
            w, c = _best(rows[2][1], board, args.rounds)
        print(f"  {'detect_gray, cornerSubPix stage only':38s} {w:7.2f} ms wall  {c:7.2f} ms CPU per image")
        walls = []
        for _ in range(args.rounds):
            t0 = time.perf_counter()
            res = detect_views(items, target)
            walls.append(time.perf_counter() - t0)
        failed = sorted(v for v, d in res.items() if isinstance(d, DetectionFailure))
        print(
            f"  detect_views, {len(items)} images, default workers: {min(walls):.3f} s wall (min of {args.rounds}), "
            f"median {np.median(walls):.3f} s; not found: {failed}"
        )

        if (Path(folder) / "ground_truth.json").exists():
            truth = _truth(Path(folder), s)
            err = np.concatenate(
                [
                    np.linalg.norm(res[v].image_points - truth[v][res[v].corner_ids], axis=1)
                    for v in truth
                    if v in res and not isinstance(res[v], DetectionFailure)
                ]
            )
            print(
                f"  corner error against the truth: RMS {np.sqrt(np.mean(err**2)):.4f} px, max {err.max():.4f} px, "
                f"{len(err)} corners used"
            )
            with _one_stage():
                one = [(detect_gray(g, target), truth[vid]) for vid, g, _ in board if vid in truth]
            e1 = np.concatenate(
                [
                    min((np.linalg.norm(d[1] - t[ids], axis=1) for ids in (d[0], len(t) - 1 - d[0])), key=np.max)
                    for d, t in one
                    if not isinstance(d, str)
                ]
            )
            print(
                f"  corner error, cornerSubPix stage only: RMS {np.sqrt(np.mean(e1**2)):.4f} px, max {e1.max():.4f} px"
            )
            # cornerSubPix stopping rules from the same starting corners (half-size search, scaled)
            starts = []
            for vid, g, _ in board:
                h, w = g.shape
                small = cv2.resize(g, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
                ok, c = cv2.findChessboardCorners(
                    small,
                    (target.cols, target.rows),
                    flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK,
                )
                if ok:
                    p0, win = subpix_windows(board_squares(target), (c.reshape(-1, 2) + 0.5) * 2 - 0.5, o)
                    starts.append((vid, g, p0.astype(np.float32), win))
            for it, eps in ((50, 1e-4), (o.subpix_max_iter, o.subpix_eps_px)):
                rule = replace(o, subpix_max_iter=it, subpix_eps_px=eps)
                best, out = 1e9, None
                for _ in range(args.rounds):
                    c0 = time.process_time()
                    out = [refine_corners(g, p, win, rule) for _, g, p, win in starts]
                    best = min(best, (time.process_time() - c0) / len(starts) * 1e3)
                e = np.concatenate(
                    [np.linalg.norm(p - truth[vid], axis=1) for p, (vid, *_) in zip(out, starts, strict=False)]
                )
                print(
                    f"  cornerSubPix max_iter {it} eps {eps:g}: {best:.2f} ms CPU per view, "
                    f"error RMS {np.sqrt(np.mean(e**2)):.4f} px, max {e.max():.4f} px"
                )

        _wrong_size(Path(folder), Path(tmp), args.rounds)
        for k in args.supersample:
            _low_texture(args.views, args.rounds, k)
        _big_noise_image(Path(folder), Path(tmp), args.big)
        _timed_out(items, target, failed)

    for folder in args.real:
        _real_subpix(folder, tuple(args.real_board))
    if not args.no_shared:
        for name, size in SHARED_CHESSBOARDS.items():
            if (args.shared / name).is_dir():
                _against_accurate_sb(
                    args.shared / name, size, VISP_K if name == "visp-franka-eye-in-hand" else None, crops=args.crops
                )
        visp = args.shared / "visp-franka-eye-in-hand"
        if visp.is_dir():
            _sb_on_replicas(visp, SHARED_CHESSBOARDS[visp.name], 0.0236, VISP_K)
        _ical_checks(args.shared)


def _wrong_size_sweep(n: int, tmp: Path) -> None:
    """``n`` rendered 20-view 1280x720 sessions (both modes, three boards) whose config.yaml states a wrong
    board size: refused as target_not_found, naming the size the images show, and how long it took."""
    import yaml

    from handeye.pipeline import CalibrateOptions
    from handeye.sim.vendor import write_vendor_session
    from handeye.targets import ChessboardSpec
    from handeye.workflow import calibrate_session

    boards = [ChessboardSpec(11, 8, 0.025), ChessboardSpec(9, 6, 0.03), ChessboardSpec(8, 6, 0.03)]
    named, walls = 0, []
    for k in range(n):
        b = boards[k % len(boards)]
        mode = ("eye_in_hand", "eye_to_hand")[(k // len(boards)) % 2]
        folder = write_vendor_session(
            tmp / f"ws{k}", mode=mode, n_views=20, seed=100 + k, target=b, supersample=2, workers=2
        )
        stated = [(b.cols - 2, b.rows - 1), (b.cols + 1, b.rows), (b.rows, b.cols - 1)][k % 3]
        cfg = yaml.safe_load((folder / "config.yaml").read_text())
        cfg["checkerboard_args"].update(XX=stated[0], YY=stated[1])
        (folder / "config.yaml").write_text(yaml.safe_dump(cfg))
        t0 = time.perf_counter()
        wr = calibrate_session(folder, options=CalibrateOptions(refine=False), out_dir=tmp / f"ws{k}-out", report=False)
        walls.append(time.perf_counter() - t0)
        err = wr.result.get("error") or {}
        ok = err.get("code") == "target_not_found" and f"{b.cols}x{b.rows} inner corners" in str(err.get("message"))
        named += ok
        if not ok:
            print(
                f"    missed: {b.cols}x{b.rows} stated {stated[0]}x{stated[1]}, {mode}: {err.get('code')} "
                f"{str(err.get('message'))[:160]}"
            )
    print(
        f"  wrong board size, {n} rendered 20-view sessions (11x8, 9x6, 8x6 boards, both modes, three wrong "
        f"sizes): refused naming the true size {named} / {n}; whole calibration without reports "
        f"{np.median(walls):.2f} s wall median, {max(walls):.2f} s max (session {int(np.argmax(walls)) + 1}), "
        f"{sum(w < 3.0 for w in walls)} under 3 s"
    )


def _wrong_size(folder: Path, tmp: Path, rounds: int) -> None:
    """Time the refusal of a session whose config.yaml states 9x6 inner corners for an 11x8 board."""
    import yaml

    from handeye.pipeline import CalibrateOptions
    from handeye.workflow import calibrate_session

    bad = tmp / "wrong-size"
    bad.mkdir()
    for f in folder.iterdir():
        if f.name != "config.yaml":
            (bad / f.name).symlink_to(f.resolve())
    cfg = yaml.safe_load((folder / "config.yaml").read_text())
    cfg["checkerboard_args"].update(XX=9, YY=6)
    (bad / "config.yaml").write_text(yaml.safe_dump(cfg))
    s = load_session(bad)
    items = [(v.view_id, v.image_path) for v in s.views]
    walls, cpus = [], []
    for _ in range(rounds):
        t0, c0 = time.perf_counter(), time.process_time()
        res = detect_views(items, s.target)
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    surveyed = sum(getattr(d, "seen_sizes", None) is not None for d in res.values())
    print(
        f"  wrong board size (9x6 stated, 11x8 board), {len(items)} images: detect_views {min(walls):.3f} s wall "
        f"(min of {rounds}), median {np.median(walls):.3f} s, CPU {min(cpus):.3f} s; every image searched, "
        f"{surveyed} surveyed for the sizes they show"
    )
    t0 = time.perf_counter()
    wr = calibrate_session(bad, options=CalibrateOptions(refine=False), out_dir=tmp / "wrong-size-out", report=False)
    print(
        f"  wrong board size, whole calibration without reports: {time.perf_counter() - t0:.2f} s wall, "
        f"exit code {wr.exit_code}: {wr.result['error']['message']}"
    )


#: the real chessboard sets of ../shared/data and their inner corners (cols, rows), from each SOURCE.md
SHARED_CHESSBOARDS = {"ur3-eyetohand-cam1": (9, 7), "ur3-eyetohand-cam2": (9, 7), "visp-franka-eye-in-hand": (9, 6)}
#: the ViSP set's shipped camera matrix (franka_camera.xml, no distortion; its square is 23.6 mm, SOURCE.md)
VISP_K = np.array([[607.593, 0, 323.463], [0, 607.575, 243.255], [0, 0, 1]])
#: a board with few, large squares (the low-texture case): 5x4 inner corners of 60 mm
LOW_TEXTURE = ChessboardSpec(5, 4, 0.06)


def _low_texture(n_views: int, rounds: int, supersample: int = 4) -> None:
    """Corner error against the rendered truth and time per image on 1280x720 views of LOW_TEXTURE, rendered
    with ``supersample`` x ``supersample`` samples per pixel (more samples: the renderer's own share of the
    error, its edges placed to 1 / (2 x supersample) px where they run along the pixel rows, shrinks)."""
    from handeye.sim.corners import make_corner_session
    from handeye.sim.render import render_view
    from handeye.sim.scenarios import default_intrinsics

    intr = default_intrinsics(1280, 720)
    cs = make_corner_session(n_views=n_views, seed=0, noise_px=0.0, intrinsics=intr, target=LOW_TEXTURE)
    imgs = [(render_view(LOW_TEXTURE, intr, T, supersample=supersample), T) for T in cs.T_cam_board_true]
    for what, stage in (("cornerSubPix stage only", _one_stage), ("both stages", contextlib.nullcontext)):
        with stage():
            found = [(img, T, detect_gray(img, LOW_TEXTURE)) for img, T in imgs]
            w, c = _best(lambda img, T, d: detect_gray(img, LOW_TEXTURE), found, rounds)
        err = np.concatenate(
            [
                np.linalg.norm(d[1] - pixels_from_board_points(T, LOW_TEXTURE.object_points()[d[0]], intr), axis=1)
                for _, T, d in found
                if not isinstance(d, str)
            ]
        )
        n = sum(not isinstance(d, str) for *_, d in found)
        print(
            f"  low-texture board ({LOW_TEXTURE.describe()}), {what}, {n}/{len(found)} of 1280x720 views "
            f"({supersample}x{supersample} samples per pixel) found: "
            f"{len(err)} corners used, error RMS {np.sqrt(np.mean(err**2)):.4f} px, max {err.max():.4f} px; "
            f"detect_gray {w:.2f} ms wall, {c:.2f} ms CPU"
        )


def _big_noise_image(folder: Path, tmp: Path, size: tuple) -> None:
    """A noise image of ``size`` (8000x6000): its detection alone, and a session of three views of that size
    (the noise image, then views 2 and 3 of the rendered session enlarged and padded to it), calibrated
    without reports (too few views: refused after detection)."""
    from handeye.pipeline import CalibrateOptions
    from handeye.workflow import calibrate_session

    w, h = size
    big = tmp / "big-noise"
    big.mkdir()
    (big / "config.yaml").write_text((folder / "config.yaml").read_text())
    (big / "poses.txt").write_text("".join((folder / "poses.txt").read_text().splitlines(keepends=True)[:3]))
    noise = np.random.default_rng(0).integers(0, 256, (h, w), dtype=np.uint8)
    cv2.imwrite(str(big / "1.jpg"), noise, [cv2.IMWRITE_JPEG_QUALITY, 95])
    for k in (2, 3):
        g = read_gray(folder / f"{k}.jpg")
        s = min(w / g.shape[1], h / g.shape[0])
        g = cv2.resize(g, (round(g.shape[1] * s), round(g.shape[0] * s)), interpolation=cv2.INTER_LINEAR)
        canvas = np.full((h, w), 128, np.uint8)
        canvas[: g.shape[0], : g.shape[1]] = g
        cv2.imwrite(str(big / f"{k}.jpg"), canvas, [cv2.IMWRITE_JPEG_QUALITY, 95])
    s = load_session(big)
    for vid in ("1", "2"):
        t0, c0 = time.perf_counter(), time.process_time()
        d = detect_image(vid, big / f"{vid}.jpg", s.target)
        what = f"{len(d.corner_ids)} corners" if isinstance(d, Detection) else d.reason
        print(
            f"  {w}x{h} {'noise image' if vid == '1' else 'view with the board'}: detect_image "
            f"{time.perf_counter() - t0:.2f} s wall, {time.process_time() - c0:.2f} s CPU: {what}"
        )
    t0, c0 = time.perf_counter(), time.process_time()
    wr = calibrate_session(big, options=CalibrateOptions(refine=False), out_dir=tmp / "big-noise-out", report=False)
    err = (wr.result.get("error") or {}).get("message", "")
    print(
        f"  session of these three {w}x{h} views, whole calibration without reports: "
        f"{time.perf_counter() - t0:.2f} s wall, {time.process_time() - c0:.2f} s CPU, exit code {wr.exit_code}"
        + (f": {err}" if err else "")
    )


def _timed_out(items, target, failed) -> None:
    """A view without the board under a budget of 1 ms: dropped as timed out after the first search."""
    o = replace(default_options(), time_budget_s=1e-3)
    for vid, path in items:
        if vid in failed:
            t0 = time.perf_counter()
            d = detect_image(vid, path, target, options=o)
            print(
                f"  view {vid} (no board) with time_budget_s 0.001: {(time.perf_counter() - t0) * 1e3:.0f} ms wall: "
                f"{d.reason}"
            )
            return


def _pnp_residual_px(obj: np.ndarray, pts: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Distance of each corner from the board pose solvePnP fits to all of them (no distortion), px."""
    _, rvec, tvec = cv2.solvePnP(obj, pts, K, None)
    return np.linalg.norm(cv2.projectPoints(obj, rvec, tvec, K, None)[0].reshape(-1, 2) - pts, axis=1)


def _against_accurate_sb(folder: Path, size: tuple, K: np.ndarray | None = None, crops: Path | None = None) -> None:
    """Corners of detect_gray against findChessboardCornersSB (EXHAUSTIVE | ACCURACY) where both detect
    (SB may number the board from the other end: the nearer numbering is compared), the corners not used,
    the time of each (and of detect_gray with the cornerSubPix stage only), and for the corners over 1 px
    from SB which of the two agrees with its board neighbours (the geometric check's residual) and, given
    the camera matrix ``K``, with the board pose solvePnP fits to each detector's corners of the view. Last,
    which corners a camera model explains better: cv2.calibrateCamera on the views both detect, once with
    each detector's corners (the RMS reprojection error of each). ``crops``: a folder for an 8x enlarged crop of
    each corner over 1 px from SB with both marks (to look at which one sits on the junction)."""
    spec = ChessboardSpec(size[0], size[1], 1.0)
    bxy, o = board_squares(spec), default_options()
    d_max, n_both, n_img, ours_s, one_s, sb_s, checks, n_used, apart = [], 0, 0, 0.0, 0.0, 0.0, [], 0, []
    edge_d, edge_far = [], []  # (ours, SB's) distance from the edge-line intersection: every inner corner, those apart
    calib = ([], [], [])  # board points, our corners, SB's, per view both detect
    image_size = None
    for p in sorted(q for q in folder.rglob("*") if q.suffix.lower() in (".png", ".jpg", ".jpeg")):
        g = read_gray(p)
        n_img += 1
        both, one = [], []
        for _ in range(3):  # the least of three, alternated (the load of a shared machine changes)
            c0 = time.process_time()
            out = detect_gray(g, spec)
            c1 = time.process_time()
            with _one_stage():
                detect_gray(g, spec)
            both.append(c1 - c0)
            one.append(time.process_time() - c1)
        c2 = time.process_time()
        ok, ref = cv2.findChessboardCornersSB(
            g, size, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
        )
        sb_s += time.process_time() - c2
        ours_s += min(both)
        one_s += min(one)
        if isinstance(out, str) or not ok:
            continue
        ids, pts = out
        checks.append(check_corners(bxy[ids], pts, o))
        ref = ref.reshape(-1, 2).astype(np.float64)
        ref = min((ref, ref[::-1]), key=lambda r: np.max(np.linalg.norm(pts - r[ids], axis=1)))
        image_size = (g.shape[1], g.shape[0])
        for lst, a in zip(calib, (spec.object_points()[ids], pts, ref[ids]), strict=False):
            lst.append(np.asarray(a, np.float32))
        d = np.linalg.norm(pts - ref[ids], axis=1)
        d_max.append(d)
        edges = _edge_line_distances(g, size, ids, pts, ref)
        edge_d += [(e[1], e[2]) for e in edges]
        edge_far += [e[1:] for e in edges if d[np.flatnonzero(ids == e[0])[0]] > 1]
        n_both += 1
        n_used += len(ids)
        far = d > 1
        if far.any():
            ours = check_corners(bxy[ids], pts, o).residual_px[far]
            theirs = check_corners(bxy, ref, o).residual_px[ids[far]]
            obj = spec.object_points()
            pnp = (
                (_pnp_residual_px(obj[ids], pts, K)[far], _pnp_residual_px(obj, ref, K)[ids[far]])
                if K is not None
                else (np.full(far.sum(), np.nan),) * 2
            )
            apart += list(zip(ours, theirs, *pnp, strict=False))
            if crops is not None:
                for k in np.flatnonzero(far):
                    _write_crop(crops / f"{folder.name}-{p.stem}-corner{ids[k]}.png", g, pts[k], ref[ids[k]])
    d = np.concatenate(d_max) if d_max else np.zeros(1)
    print(
        f"  {folder.name}: {n_both} of {n_img} images detected by both; {n_used} of {n_both * spec.n_corners} corners "
        f"used; corners from the accurate SB: RMS {np.sqrt(np.mean(d**2)):.3f} px, max {d.max():.3f} px, "
        f"{int((d > 1).sum())} over 1 px; detect_gray {ours_s / n_img * 1e3:.1f} ms CPU per image (cornerSubPix stage "
        f"only {one_s / n_img * 1e3:.1f} ms, SB accurate {sb_s / n_img * 1e3:.0f} ms)"
    )
    for ours, theirs, pnp_ours, pnp_sb in apart:
        print(
            f"    a corner {'' if ours < theirs else 'NOT '}nearer its neighbours' homography than SB's: "
            f"{ours:.2f} px against SB's {theirs:.2f} px"
            + (
                ""
                if np.isnan(pnp_ours)
                else f"; from the view's solvePnP pose {pnp_ours:.2f} px against SB's {pnp_sb:.2f} px"
            )
        )
    if edge_d:
        e = np.array(edge_d)
        print(
            f"    the intersection of each inner corner's two edge lines (neither detector's method; "
            f"{len(e)} corners): ours RMS {np.sqrt(np.mean(e[:, 0] ** 2)):.3f} px from it, SB's "
            f"{np.sqrt(np.mean(e[:, 1] ** 2)):.3f} px"
            + (
                ""
                if not edge_far
                else "; the inner corners over 1 px "
                "from SB: " + ", ".join(f"ours {a:.2f} / SB {b:.2f} px" for a, b in edge_far)
            )
        )
    if len(calib[0]) >= 3:
        rms = [cv2.calibrateCamera(calib[0], c, image_size, None, None)[0] for c in calib[1:]]
        print(
            f"    cv2.calibrateCamera on the {len(calib[0])} views both detect: RMS {rms[0]:.3f} px with detect_gray's "
            f"corners, {rms[1]:.3f} px with SB's"
        )
    _print_checks(folder.name, checks)


def _edge_line_corner(gray: np.ndarray, at: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """A corner found by neither detector's method: the intersection of the board's two edge lines through it.
    ``neighbours`` (4, 2): the adjacent corners left, right, up, down. Along each of the four edges from ``at``
    toward a neighbour (20-80 % of the way), the edge's crossing of 25 profiles across it (8 px long, the
    centroid of the squared intensity gradient); a straight line through the crossings of opposite edges
    (a straight board edge stays straight in an undistorted image), and the two lines' intersection."""
    s = np.arange(-4.0, 4.01, 0.1)
    t = np.linspace(0.2, 0.8, 25)
    lines = []
    for pair in ((0, 1), (2, 3)):
        u = neighbours[list(pair)] - at  # (2, 2)
        n = np.c_[-u[:, 1], u[:, 0]] / np.linalg.norm(u, axis=1)[:, None]
        base = at + t[None, :, None] * u[:, None, :]  # (2, 25, 2)
        pts = (base[:, :, None, :] + s[None, None, :, None] * n[:, None, None, :]).astype(np.float32)
        prof = cv2.remap(gray, pts[..., 0].reshape(-1, s.size), pts[..., 1].reshape(-1, s.size), cv2.INTER_LINEAR)
        w = np.gradient(prof.astype(np.float64), axis=1) ** 2
        off = (w @ s) / w.sum(axis=1)
        P = base.reshape(-1, 2) + off[:, None] * np.repeat(n, t.size, axis=0)
        m = P.mean(axis=0)
        lines.append((m, np.linalg.svd(P - m)[2][0]))
    (m1, d1), (m2, d2) = lines
    return m1 + np.linalg.solve(np.c_[d1, -d2], m2 - m1)[0] * d1


def _edge_line_distances(gray: np.ndarray, size: tuple, ids: np.ndarray, ours: np.ndarray, sb: np.ndarray):
    """For each corner with its four neighbours detected: (id, distance of ours, of SB's) from the edge-line
    intersection (:func:`_edge_line_corner`, sampled around the two detectors' midpoint)."""
    pos = dict(zip(ids.tolist(), ours, strict=False))
    out = []
    for i, q in pos.items():
        nb = [pos.get(j) for j in (i - 1, i + 1, i - size[0], i + size[0])]
        if i % size[0] in (0, size[0] - 1) or any(x is None for x in nb):
            continue
        X = _edge_line_corner(gray, 0.5 * (q + sb[i]), np.array(nb))
        out.append((i, np.linalg.norm(X - q), np.linalg.norm(X - sb[i])))
    return out


def _write_crop(path: Path, gray: np.ndarray, ours: np.ndarray, sb: np.ndarray, half: int = 20, zoom: int = 8) -> None:
    """A (2 half + 1) px square of ``gray`` around ``ours`` enlarged ``zoom`` times (each pixel a block, its centre
    at the block's centre), our corner marked red and SB's green."""
    x0, y0 = np.maximum(np.round(ours).astype(int) - half, 0)
    crop = cv2.resize(
        gray[y0 : y0 + 2 * half + 1, x0 : x0 + 2 * half + 1], None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST
    )
    crop = cv2.cvtColor(crop, cv2.COLOR_GRAY2BGR)
    for q, colour in ((ours, (0, 0, 255)), (sb, (0, 255, 0))):
        cv2.circle(crop, tuple(int(c) for c in (np.asarray(q) - (x0, y0) + 0.5) * zoom), 3, colour, -1)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), crop)
    print(f"    crop: {path}")


def _sb_on_replicas(folder: Path, size: tuple, square_m: float, K: np.ndarray) -> None:
    """Both detectors against the truth on rendered replicas of a real set: every view rendered (640x480,
    4x4 samples per pixel, 1 grey level of noise) from the board pose solvePnP gives for its detected corners,
    sharp and smoothed by a Gaussian of 0.7 and 1.2 px (which of the two is right where they disagree on
    the real images), and the edge-line intersection of the real images' inner corners (its own error here)."""
    from handeye.sim.render import render_view

    spec = ChessboardSpec(size[0], size[1], square_m)
    obj = spec.object_points()
    rng = np.random.default_rng(0)
    images = sorted(q for q in folder.rglob("*") if q.suffix.lower() in (".png", ".jpg", ".jpeg"))
    h, w = read_gray(images[0]).shape
    intr = Intrinsics.from_K(K, np.zeros(5), w, h)
    poses = []
    for p in images:
        out = detect_gray(read_gray(p), spec)
        if not isinstance(out, str):
            _, rvec, tvec = cv2.solvePnP(obj[out[0]], out[1], K, None)
            T = np.eye(4)
            T[:3, :3], T[:3, 3] = cv2.Rodrigues(rvec)[0], tvec.ravel()
            poses.append(T)
    for blur in (0.0, 0.7, 1.2):
        ours, sb, edge = [], [], []
        for T in poses:
            img = render_view(spec, intr, T, supersample=4, blur_sigma_px=blur, noise_sigma=1.0, rng=rng)
            truth = pixels_from_board_points(T, obj, intr)
            out = detect_gray(img, spec)
            ok, ref = cv2.findChessboardCornersSB(
                img, size, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_NORMALIZE_IMAGE
            )
            if not isinstance(out, str):
                ours.append(min((np.linalg.norm(out[1] - t[out[0]], axis=1) for t in (truth, truth[::-1])), key=np.max))
            if ok:
                sb.append(
                    min((np.linalg.norm(ref.reshape(-1, 2) - t, axis=1) for t in (truth, truth[::-1])), key=np.max)
                )
            ids = np.arange(len(obj))
            edge += [e[1] for e in _edge_line_distances(img, size, ids, truth, truth)]  # truth as both starts
        for name, e in (("detect_gray", ours), ("SB accurate", sb), ("edge-line intersection", [np.array(edge)])):
            e = np.concatenate(e) if e else np.zeros(1)
            print(
                f"  {folder.name} rendered replicas, blur {blur:.1f} px: {name} "
                f"error RMS {np.sqrt(np.mean(e**2)):.3f} px, "
                f"max {e.max():.3f} px, {int((e > 0.5).sum())} over 0.5 px"
            )


def _print_checks(name: str, checks) -> None:
    """The geometric check's worst corner over a set's views: px, and the largest share of its limit."""
    res = [np.nanmax(c.residual_px) for c in checks if c.worst >= 0]
    share = [np.nanmax(c.residual_px / c.limit_px) for c in checks if c.worst >= 0]
    if res:
        print(
            f"  {name}: geometric check over {len(res)} views: worst corner {max(res):.2f} px from its neighbours' "
            f"homography (median view {np.median(res):.2f} px), at most {max(share):.2f} of its limit"
        )


def _ical_checks(shared: Path) -> None:
    """The geometric check on the ical ChArUco and circle-grid sets (corners as detected before the check
    drops any)."""
    from handeye.session.importers import import_ical

    loose = replace(default_options(), grid_check_max_px=1e9)
    for name, kw in (
        ("ical-mako-charuco-eye-to-hand", {"image_dir": "images_gray"}),
        ("ical-kinect-circlegrid-eye-in-hand", {}),
    ):
        if not (shared / name).is_dir():
            continue
        with tempfile.TemporaryDirectory() as tmp:
            s = load_session(import_ical(shared / name, Path(tmp) / "s", **kw))
            checks = []
            for v in s.views:
                out = detect_gray(read_gray(v.image_path), s.target, options=loose)
                if not isinstance(out, str):
                    checks.append(check_corners(s.target.object_points()[out[0], :2], out[1], default_options()))
        _print_checks(name, checks)


def _real_subpix(folder: Path, size: tuple) -> None:
    o = default_options()
    data = []
    for p in sorted(q for q in folder.rglob("*") if q.suffix.lower() in (".png", ".jpg", ".jpeg")):
        g = read_gray(p)
        ok, c = cv2.findChessboardCorners(
            g, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
        )
        if ok:
            p0, win = subpix_windows(board_squares(ChessboardSpec(size[0], size[1], 1.0)), c.reshape(-1, 2), o)
            data.append((g, p0.astype(np.float32), win))
    ref = None
    for it, eps in ((50, 1e-4), (o.subpix_max_iter, o.subpix_eps_px)):
        rule = replace(o, subpix_max_iter=it, subpix_eps_px=eps)
        c0 = time.process_time()
        out = [refine_corners(g, p, w, rule) for g, p, w in data]
        ms = (time.process_time() - c0) / max(len(data), 1) * 1e3
        ref = out if ref is None else ref
        d = (
            np.concatenate([np.linalg.norm(a - b, axis=1) for a, b in zip(out, ref, strict=False)])
            if data
            else np.zeros(1)
        )
        print(
            f"  {folder.name}: {len(data)} views, cornerSubPix max_iter {it} eps {eps:g}: {ms:.2f} ms CPU per view; "
            f"corners moved against 50 / 1e-4: RMS {np.sqrt(np.mean(d**2)):.4f} px, max {d.max():.4f} px"
        )


if __name__ == "__main__":
    main()
