"""Target detection behind one dispatcher: chessboard (:mod:`.chessboard`), ChArUco (:mod:`.charuco`)
and circle grid (:mod:`.circlegrid`), plus the image-quality measures (:mod:`.quality`) taken from
the same decoded image.

:func:`detect_gray` finds the target in a grey image; :func:`detect_image` reads one file and returns
a :class:`~handeye.records.Detection` (corners, sharpness, blur, exposure, thumbnail) or a
:class:`~handeye.records.DetectionFailure` (reason, exposure, thumbnail), each with its view id, so the
caller drops a failed view *together with its pose*. :func:`detect_views` does a whole session in
parallel threads (OpenCV releases the GIL); for a chessboard it first looks at a few views, and when
they show another board size (:mod:`.board_size`) it stops there instead of running the slow search
on every image. Thresholds are in configs/detection.yaml.
"""

from __future__ import annotations

import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np

from ..errors import ConfigError, InputError
from ..records import Detection, DetectionFailure
from ..targets import TargetSpec
from .board_size import SizeSurvey as SizeSurvey  # re-exported
from .board_size import board_size_verdict, normal_size, size_text, visible_grid_sizes
from .board_size import size_survey as size_survey  # re-exported
from .charuco import detect_charuco
from .chessboard import detect_chessboard, normalize_chessboard_order, order_cue
from .circlegrid import detect_circlegrid
from .geometry import TimeBudget
from .markers import detect_markers
from .options import DetectionOptions, default_options
from .quality import image_exposure, sharpness, thumbnail_jpeg, view_blur, view_exposure

log = logging.getLogger(__name__)

#: the detector of each target kind (``TargetSpec.kind``)
DETECTORS: dict[str, Callable[..., Any]] = {
    "chessboard": detect_chessboard,
    "charuco": detect_charuco,
    "circlegrid": detect_circlegrid,
    "marker": detect_markers,
    "aprilgrid": detect_markers,
}
#: detectors with slower fallback searches, which take the image's time budget (``budget=``)
_BUDGETED = (detect_chessboard, detect_circlegrid)
_DROPPING = (detect_chessboard, detect_charuco)  # report the corners they leave out (``dropped=``)
_JPEG_MAGIC = b"\xff\xd8\xff"


def read_gray(path: Path) -> np.ndarray:
    """Read an image as 8-bit grayscale; one-line InputError when missing or corrupt.

    JPEGs are decoded straight to their luma channel (about 2 ms CPU for a 1280x720 view against
    3-5.6 ms for the colours and a conversion, benchmarks/bench_detect.py; within 1-2 grey levels of
    the converted colours); other formats keep their bit depth until they are scaled to 8 bits.
    """
    path = Path(path)
    if not path.exists():
        raise InputError("image file missing", path=path, hint="restore it or remove its pose from the session")
    data = np.fromfile(str(path), dtype=np.uint8)
    img = None
    if data.size:
        jpeg = data[:3].tobytes() == _JPEG_MAGIC
        img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE if jpeg else cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(
            "image cannot be decoded (corrupt or not an image)",
            path=path,
            hint="re-capture the view or remove the image and its pose",
        )
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)  # type: ignore[call-overload]
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    return img


def detect_gray(
    gray: np.ndarray,
    target: TargetSpec,
    *,
    min_corners: int | None = None,
    options: DetectionOptions | None = None,
    budget: TimeBudget | None = None,
    dropped: list | None = None,
) -> tuple[np.ndarray, np.ndarray] | str:
    """(corner ids, image points (N,2) px) of ``target`` in an 8-bit grey image.

    (corner ids, image points (N,2) px) of ``target`` in an 8-bit grey image, or the reason it was
    not found. Fewer than ``min_corners`` corners (default: configs/detection.yaml) counts as not found.
    ``budget``: the time left for this image (default: ``time_budget_s`` from now); detectors with slower
    searches skip them once it is spent (the reason then says "detection timed out"). ``dropped``: a list
    that receives (corner id, reason) of the corners found but not used (chessboard, ChArUco).
    """
    o = options or default_options()
    detector = DETECTORS.get(getattr(target, "kind", ""))
    if detector is None:
        raise ConfigError("no detector for this target", expected=" | ".join(DETECTORS), received=repr(target))
    # the preset's floor is capped at the target's corners (one marker has 4: it must show them all); a
    # floor asked for explicitly is kept
    need = min(o.min_corners, target.n_corners) if min_corners is None else min_corners
    kw: dict[str, Any] = {"budget": budget or TimeBudget(o.time_budget_s)} if detector in _BUDGETED else {}
    if detector in _DROPPING and dropped is not None:
        kw["dropped"] = dropped
    out = detector(gray, target, options=o, **kw)
    if isinstance(out, str):
        return out
    ids, pts = out
    if len(ids) < need:
        return f"only {len(ids)} corners detected (need at least {need})"
    return ids, pts


def detect_image(
    view_id: str,
    path: Path,
    target: TargetSpec,
    *,
    min_corners: int | None = None,
    options: DetectionOptions | None = None,
) -> Detection | DetectionFailure:
    """Detect the target in one image file and measure the image while it is decoded."""
    o = options or default_options()
    t0 = time.perf_counter()
    budget = TimeBudget(o.time_budget_s)
    gray = read_gray(path)
    size = (gray.shape[1], gray.shape[0])
    dropped: list = []
    out = detect_gray(gray, target, min_corners=min_corners, options=o, budget=budget, dropped=dropped)
    if isinstance(out, str):
        return _failure(view_id, gray, out, o, t0)
    thumb = thumbnail_jpeg(gray, width_px=o.thumbnail_width_px, quality=o.thumbnail_jpeg_quality)
    ids, pts = out
    cue = order_cue(gray, pts, target.cols, target.rows, ids) if target.kind == "chessboard" else float("nan")
    blur = view_blur(
        gray,
        pts,
        ids,
        target.object_points(),
        target.square_m,
        charuco=target.kind == "charuco",
        sharp_edge_sigma_px=o.sharp_edge_sigma_px,
    )
    return Detection(
        view_id=view_id,
        corner_ids=ids,
        image_points=pts,
        image_size=size,
        sharpness=sharpness(gray, pts),
        order_cue=cue,
        blur=blur,
        exposure=view_exposure(gray, pts, saturated_grey=o.saturated_grey),
        thumbnail_jpeg=thumb,
        seconds=time.perf_counter() - t0,
        dropped_corners=tuple(sorted(dropped)),
    )


def detect_views(
    items: Sequence[tuple[str, Path]],
    target: TargetSpec,
    *,
    workers: int | None = None,
    min_corners: int | None = None,
    options: DetectionOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> dict[str, Detection | DetectionFailure]:
    """Detect the target in every (view_id, image_path); results keyed by view id.

    Chessboards: when the first views show another board size, the others are not searched
    (:func:`_wrong_board_size`); when the stated board is missing from most views after a full search,
    a few of them are checked for the sizes they show. Either way the checked failures keep those
    sizes (``DetectionFailure.seen_sizes``; :func:`size_survey` words them). Unreadable images raise
    InputError (naming the file) after all workers finish; images of different sizes raise InputError
    too (one camera at one resolution per session).
    """
    o = options or default_options()
    workers = workers or min(len(items), os.cpu_count() or 1) or 1
    results: dict[str, Detection | DetectionFailure] = {}

    def job(item):
        vid, path = item
        return vid, detect_image(vid, path, target, min_corners=min_corners, options=o)

    with ThreadPoolExecutor(max_workers=workers) as pool:
        todo = list(items)
        if target.kind == "chessboard":
            refused = _wrong_board_size(items, target, pool, o)
            if refused is not None:
                results, todo = refused, []
                if progress:
                    progress(len(items), len(items))
        for k, (vid, res) in enumerate(pool.map(job, todo), start=1):
            results[vid] = res
            if progress:
                progress(k, len(items))
        if target.kind == "chessboard" and todo:
            results = _sizes_of_failures(results, dict(items), pool, o)
    if target.kind == "chessboard":
        results = normalize_chessboard_order(results, target, options=o)
    sizes = {d.image_size for d in results.values() if d.image_size is not None}
    if len(sizes) > 1:
        raise InputError(
            f"images have different sizes {sorted(sizes)}",
            path=Path(items[0][1]).parent,
            hint="all views of a session must come from one camera at one resolution",
        )
    return results


def _wrong_board_size(items, target, pool, o: DetectionOptions) -> dict | None:
    """Failures for every view when the first views show another chessboard size than ``target``'s.

    Failures for every view when the first views show another chessboard size than ``target``'s;
    None (search every view as usual) when one of them shows the stated size or they do not clearly
    show another one. The first view is looked at alone (a session with the right size pays for that
    one look, 50-100 ms), the others of the probe together. Checked views keep the sizes seen
    (``seen_sizes``); the others are decoded only for their thumbnail and exposure, and say they were
    not searched.
    """
    probe = list(items[: o.size_probe_views])
    if len(probe) < 2:
        return None
    stated = normal_size(target.cols, target.rows)
    said = f"{target.cols}x{target.rows}"

    def look(item):
        vid, path = item
        t0 = time.perf_counter()
        gray = read_gray(path)
        seen = visible_grid_sizes(gray, max_side_px=o.size_survey_max_side_px)
        why = f"chessboard {said} not found" + (
            f"; the detector sees {', '.join(size_text(s) for s in seen)} inner corners" if seen else ""
        )
        return vid, _failure(vid, gray, why, o, t0, seen_sizes=seen)

    looked = dict([look(probe[0])])
    if stated in looked[probe[0][0]].seen_sizes:
        return None
    looked.update(pool.map(look, probe[1:]))
    likely = board_size_verdict(stated, {v: f.seen_sizes for v, f in looked.items()})
    if likely is None:
        return None
    log.info(
        "chessboard %s in none of the first %d views, which show %s: the other views are not searched",
        said,
        len(probe),
        size_text(likely),
    )
    why = f"not searched: no {said} chessboard in the first {len(probe)} views, which show {size_text(likely)}"

    def skip(item):
        vid, path = item
        t0 = time.perf_counter()
        return vid, _failure(vid, read_gray(path), why, o, t0)

    out = dict(looked)
    out.update(pool.map(skip, [it for it in items if it[0] not in looked]))
    return {vid: out[vid] for vid, _ in items}


def _sizes_of_failures(results: dict, paths: dict, pool, o: DetectionOptions) -> dict:
    """The board sizes seen in a few failed views when the stated chessboard was mostly not found.

    When the stated chessboard was not found in most views (the probe could not tell why), the
    board sizes seen in a few of the failed views (``seen_sizes``), so the message can name them.
    """
    failed = [v for v, d in results.items() if isinstance(d, DetectionFailure) and d.seen_sizes is None]
    if len(failed) * 2 <= len(results):
        return results
    pick = [failed[i] for i in sorted(set(np.linspace(0, len(failed) - 1, o.size_probe_views).round().astype(int)))]

    def look(vid):
        return vid, visible_grid_sizes(
            read_gray(paths[vid]),
            max_side_px=o.size_survey_max_side_px,
            full_size_retry=True,
            retry_max_megapixels=o.search_max_megapixels,
        )

    out = dict(results)
    for vid, seen in pool.map(look, pick):
        out[vid] = replace(results[vid], seen_sizes=seen)
    return out


def _failure(vid: str, gray: np.ndarray, reason: str, o: DetectionOptions, t0: float, **kw) -> DetectionFailure:
    return DetectionFailure(
        view_id=vid,
        reason=reason,
        thumbnail_jpeg=thumbnail_jpeg(gray, width_px=o.thumbnail_width_px, quality=o.thumbnail_jpeg_quality),
        exposure=image_exposure(gray, saturated_grey=o.saturated_grey),
        image_size=(gray.shape[1], gray.shape[0]),
        seconds=time.perf_counter() - t0,
        **kw,
    )
