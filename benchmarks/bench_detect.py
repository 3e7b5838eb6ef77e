"""Detection on a rendered 1280x720 vendor session: time per image by part, the whole session, corner
accuracy against the ground truth, and the cornerSubPix stopping rule of configs/detection.yaml.

Usage: python benchmarks/bench_detect.py [--views 20] [--rounds 7] [--session DIR] [--real DIR ...]
The last lines time the refusal of a wrong board size: the session's images under a config.yaml that
states 9x6 inner corners (the board has 11x8), through detect_views and through the whole
calibration (handeye.workflow.calibrate_session without the reports), with the message it gives.
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
import json
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from handeye.camera import Intrinsics, pixels_from_board_points
from handeye.detect import DetectionFailure, detect_gray, detect_image, detect_views, read_gray
from handeye.detect.chessboard import subpix_window
from handeye.detect.options import default_options
from handeye.detect.quality import sharpness, thumbnail_jpeg, view_blur, view_exposure
from handeye.session import load_session


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
    args = ap.parse_args()
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
        print(f"session {folder}: {len(views)} images {grays[views[0].view_id].shape[1]}x"
              f"{grays[views[0].view_id].shape[0]}, target found in {len(board)}")

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
        walls = []
        for _ in range(args.rounds):
            t0 = time.perf_counter()
            res = detect_views(items, target)
            walls.append(time.perf_counter() - t0)
        failed = sorted(v for v, d in res.items() if isinstance(d, DetectionFailure))
        print(f"  detect_views, {len(items)} images, default workers: {min(walls):.3f} s wall (min of {args.rounds}), "
              f"median {np.median(walls):.3f} s; not found: {failed}")

        if (Path(folder) / "ground_truth.json").exists():
            truth = _truth(Path(folder), s)
            err = np.concatenate([np.linalg.norm(res[v].image_points - truth[v][res[v].corner_ids], axis=1)
                                  for v in truth if v in res and not isinstance(res[v], DetectionFailure)])
            print(f"  corner error against the truth: RMS {np.sqrt(np.mean(err ** 2)):.4f} px, max {err.max():.4f} px")
            # cornerSubPix stopping rules from the same starting corners (half-size search, scaled)
            starts = []
            for vid, g, _ in board:
                h, w = g.shape
                small = cv2.resize(g, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
                ok, c = cv2.findChessboardCorners(small, (target.cols, target.rows), flags=cv2.CALIB_CB_ADAPTIVE_THRESH
                                                  | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK)
                if ok:
                    p0 = (c.reshape(-1, 2) * 2).astype(np.float32)
                    starts.append((vid, g, p0, subpix_window(p0, target.cols, target.rows, o)))
            for it, eps in ((50, 1e-4), (o.subpix_max_iter, o.subpix_eps_px)):
                crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, it, eps)
                best, out = 1e9, None
                for _ in range(args.rounds):
                    c0 = time.process_time()
                    out = [cv2.cornerSubPix(g, p.reshape(-1, 1, 2).copy(), (win, win), (-1, -1), crit).reshape(-1, 2)
                           for _, g, p, win in starts]
                    best = min(best, (time.process_time() - c0) / len(starts) * 1e3)
                e = np.concatenate([np.linalg.norm(p - truth[vid], axis=1) for p, (vid, *_) in zip(out, starts)])
                print(f"  cornerSubPix max_iter {it} eps {eps:g}: {best:.2f} ms CPU per view, "
                      f"error RMS {np.sqrt(np.mean(e ** 2)):.4f} px, max {e.max():.4f} px")

        _wrong_size(Path(folder), Path(tmp), args.rounds)

    for folder in args.real:
        _real_subpix(folder, tuple(args.real_board))


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
    searched = sum(not str(getattr(d, "reason", "")).startswith("not searched") for d in res.values())
    print(f"  wrong board size (9x6 stated, 11x8 board), {len(items)} images: detect_views {min(walls):.3f} s wall "
          f"(min of {rounds}), median {np.median(walls):.3f} s, CPU {min(cpus):.3f} s; {searched} images looked at")
    t0 = time.perf_counter()
    wr = calibrate_session(bad, options=CalibrateOptions(refine=False), out_dir=tmp / "wrong-size-out", report=False)
    print(f"  wrong board size, whole calibration without reports: {time.perf_counter() - t0:.2f} s wall, "
          f"exit code {wr.exit_code}: {wr.result['error']['message']}")


def _real_subpix(folder: Path, size: tuple) -> None:
    o = default_options()
    data = []
    for p in sorted(q for q in folder.rglob("*") if q.suffix.lower() in (".png", ".jpg", ".jpeg")):
        g = read_gray(p)
        ok, c = cv2.findChessboardCorners(g, size, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
                                          | cv2.CALIB_CB_FAST_CHECK)
        if ok:
            p0 = c.reshape(-1, 2).astype(np.float32)
            data.append((g, p0, subpix_window(p0, size[0], size[1], o)))
    ref = None
    for it, eps in ((50, 1e-4), (o.subpix_max_iter, o.subpix_eps_px)):
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, it, eps)
        c0 = time.process_time()
        out = [cv2.cornerSubPix(g, p.reshape(-1, 1, 2).copy(), (w, w), (-1, -1), crit).reshape(-1, 2) for g, p, w in data]
        ms = (time.process_time() - c0) / max(len(data), 1) * 1e3
        ref = out if ref is None else ref
        d = np.concatenate([np.linalg.norm(a - b, axis=1) for a, b in zip(out, ref)]) if data else np.zeros(1)
        print(f"  {folder.name}: {len(data)} views, cornerSubPix max_iter {it} eps {eps:g}: {ms:.2f} ms CPU per view; "
              f"corners moved against 50 / 1e-4: RMS {np.sqrt(np.mean(d ** 2)):.4f} px, max {d.max():.4f} px")


if __name__ == "__main__":
    main()
