"""Target detection behind one dispatcher, with the image-quality measures of the same decoded image.

:func:`detect_gray` finds the target in a grey image; :func:`detect_image` reads one file and returns
a :class:`~handeye.records.Detection` (corners, sharpness, blur, exposure, thumbnail) or a
:class:`~handeye.records.DetectionFailure` (reason, exposure, thumbnail), each with its view id, so the
caller drops a failed view *together with its pose*. :func:`detect_views` does a whole session in
parallel threads (OpenCV releases the GIL): each image is searched on its own, whatever the others show
(a chessboard image without the stated board records the board sizes it shows, :mod:`.board_size`).
Thresholds are in configs/detection.yaml; see docs/detection.md.
"""

from __future__ import annotations

import hashlib
import logging
import os
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np

from ..errors import ConfigError, InputError
from ..records import Detection, DetectionFailure
from ..targets import MarkerSpec, TargetSpec
from .board_size import (  # noqa: F401 (SizeSurvey, board_size_verdict, size_survey: re-exported)
    SizeSurvey,
    board_size_verdict,
    normal_size,
    size_survey,
    size_text,
    visible_grid_sizes,
)
from .charuco import detect_charuco
from .chessboard import board_order, detect_chessboard, order_cue
from .circlegrid import detect_circlegrid
from .geometry import TimeBudget
from .markers import detect_markers, marker_view_blur
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
    the converted colours); other formats keep their bit depth until they are scaled to 8 bits. An EXIF
    orientation flag is not applied: the camera model and X are the sensor's, as its pixels are stored.
    """
    return _read_gray(path)[0]


def _read_gray(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(:func:`read_gray`'s image, the file's bytes it was decoded from)."""
    path = Path(path)
    if not path.exists():
        raise InputError("image file missing", path=path, hint="restore it or remove its pose from the session")
    data = np.fromfile(str(path), dtype=np.uint8)
    img = None
    if data.size:
        jpeg = data[:3].tobytes() == _JPEG_MAGIC
        # the pixels as the sensor stored them: an EXIF orientation flag would turn the camera frame (and X) by
        # 90 deg; IMREAD_UNCHANGED ignores it already
        img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION if jpeg else cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(
            "image cannot be decoded (corrupt or not an image)",
            path=path,
            hint="re-capture the view, or delete the image file: the view is then dropped with its reason "
            "(in a vendor folder keep its line in poses.txt: lines pair with images by number)",
        )
    if img.dtype != np.uint8:
        img = cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)  # type: ignore[call-overload]
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY if img.shape[2] == 4 else cv2.COLOR_BGR2GRAY)
    return img, data


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
    """Detect the target in one image file and measure the image while it is decoded.

    The outcome depends on this image alone (and the settings), never on the other views of its session.
    A chessboard that is not found keeps the board sizes the image shows (``seen_sizes``, named in the
    reason when another size is seen), so a wrongly stated size can be named from all images.
    """
    o = options or default_options()
    t0 = time.perf_counter()
    budget = TimeBudget(o.time_budget_s)
    gray, data = _read_gray(path)
    digest = hashlib.sha256(data.data).hexdigest()  # the bytes decoded are those provenance names (hashed once)
    size = (gray.shape[1], gray.shape[0])
    dropped: list = []
    out = detect_gray(gray, target, min_corners=min_corners, options=o, budget=budget, dropped=dropped)
    for k, why in dropped:  # said here, where the view is known (the detectors run on a grey image alone)
        log.info("view %s: corner %d not used: %s", view_id, k, why)
    if isinstance(out, str):
        if target.kind != "chessboard":
            return _failure(view_id, gray, out, o, t0, sha256=digest)
        seen = visible_grid_sizes(
            gray,
            max_side_px=o.size_survey_max_side_px,
            full_size_retry=True,
            retry_max_megapixels=o.search_max_megapixels,
        )
        other = [size_text(s) for s in seen if s != normal_size(target.cols, target.rows)]
        if other:
            out += f"; the detector sees {', '.join(other)} inner corners"
        return _failure(view_id, gray, out, o, t0, seen_sizes=seen, sha256=digest)
    thumb = thumbnail_jpeg(gray, width_px=o.thumbnail_width_px, quality=o.thumbnail_jpeg_quality)
    ids, pts = out
    cue = order_cue(gray, pts, target.cols, target.rows, ids) if target.kind == "chessboard" else float("nan")
    if isinstance(target, MarkerSpec):  # one marker: its four sides, not a grid of squares
        blur = marker_view_blur(gray, pts, target, sharp_edge_sigma_px=o.sharp_edge_sigma_px)
    else:
        blur = view_blur(
            gray,
            pts,
            ids,
            target.object_points(),
            target.square_m,
            charuco=target.kind == "charuco",
            sharp_edge_sigma_px=o.sharp_edge_sigma_px,
        )
    det = Detection(
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
        sha256=digest,
    )
    if target.kind == "chessboard":  # numbered from the end the board's print fixes (its own image only)
        det = board_order(det, target, min_grey=o.order_cue_min_grey)
    return det


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

    Every image is searched with :func:`detect_image`, each on its own, so an image's corners (and the
    corner order of an asymmetric chessboard) do not depend on which other views the session holds or
    their order; the time bound
    (configs/detection.yaml ``time_budget_s``) bounds the work on one image only. Chessboard failures keep
    the sizes they show (``DetectionFailure.seen_sizes``; :func:`size_survey` words them). Unreadable images raise
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
        for k, (vid, res) in enumerate(pool.map(job, items), start=1):
            results[vid] = res
            if progress:
                progress(k, len(items))
    paths = dict(items)
    err = size_mismatch_error({v: d.image_size for v, d in results.items() if d.image_size is not None}, paths.get)
    if err is not None:
        raise err
    return results


def size_mismatch_error(sizes: dict, path_of: Callable[[str], Any]) -> InputError | None:
    """InputError naming the first view whose image is not the size most views' are; None when all are one size.

    ``sizes``: view id -> (width, height); ``path_of``: view id -> its image's path.
    """
    from collections import Counter

    if len(set(sizes.values())) <= 1:
        return None
    common, n_common = Counter(sizes.values()).most_common(1)[0]
    odd = [vid for vid, s in sizes.items() if s != common]
    vid = odd[0]
    w, h = sizes[vid]
    return InputError(
        f"view {vid}: image is {w}x{h}, the other {n_common} views' are {common[0]}x{common[1]}"
        + (f" ({len(odd)} views differ: {', '.join(odd[:5])})" if len(odd) > 1 else ""),
        path=path_of(vid),
        expected=f"{common[0]}x{common[1]} (one camera, one resolution)",
        hint="remove the view or replace its image by one from the same camera",
    )


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
