"""Which chessboard sizes the images show, so a wrongly stated board size is named.

:func:`visible_grid_sizes` counts the inner corners of the chessboard a detector sees in one image,
whatever size the session states (``cv2.findChessboardCornersSB`` with ``CALIB_CB_LARGER`` from a 3x3
seed returns the whole grid it can follow), on a reduced copy of the image (25-80 ms at 640x360); every
image where the stated board is not found records it. :func:`board_size_verdict` names another size only
when most of the searched images show it; :class:`SizeSurvey` words it. Sizes are ``(cols, rows)`` inner
corners with cols >= rows: OpenCV finds an 11x8 pattern as 8x11 too, so orientation does not matter.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Mapping, Optional

import cv2
import numpy as np

Size = tuple  # (cols, rows) inner corners, cols >= rows

#: the grid the search starts from and grows (``CALIB_CB_LARGER``). A grid no larger than it is no evidence of a
#: board: the detector finds one in checker-like textures, e.g. a blurred background without the board.
SEED = (3, 3)


def normal_size(cols: int, rows: int) -> Size:
    """``(cols, rows)`` with the longer side first (the orientation a detector cannot tell)."""
    return (max(int(cols), int(rows)), min(int(cols), int(rows)))


def size_text(size: Size) -> str:
    return f"{size[0]}x{size[1]}"


def visible_grid_sizes(
    gray: np.ndarray, *, max_side_px: int = 800, full_size_retry: bool = False, retry_max_megapixels: float = 1.0
) -> tuple:
    """Inner-corner sizes ``((cols, rows), ...)`` of the chessboards seen in an 8-bit grey image.

    Inner-corner sizes ``((cols, rows), ...)`` of the chessboards seen in an 8-bit grey image
    (at most one: the largest grid the detector follows); ``()`` when none, or only the search's 3x3 seed.

    The image is reduced so its longer side is at most ``max_side_px``; ``full_size_retry`` searches
    the full image too when the reduced one shows nothing (small boards; 150-300 ms at 1280x720), or
    a copy reduced to ``retry_max_megapixels`` when the image is larger (the search's time grows with
    the area: configs/detection.yaml ``search_max_megapixels``).
    """
    h, w = gray.shape[:2]
    scales = [min(1.0, max_side_px / max(h, w))]
    retry = min(1.0, float(np.sqrt(retry_max_megapixels * 1e6 / (w * h))))
    if full_size_retry and scales[0] < retry:
        scales.append(retry)
    for s in scales:
        img = gray if s == 1.0 else cv2.resize(gray, (round(w * s), round(h * s)), interpolation=cv2.INTER_AREA)
        found, _, meta = cv2.findChessboardCornersSBWithMeta(
            img, SEED, flags=cv2.CALIB_CB_LARGER | cv2.CALIB_CB_NORMALIZE_IMAGE
        )
        if found and meta is not None and meta.ndim == 2:
            rows, cols = meta.shape
            if (rows, cols) == SEED:  # the seed and no more: found in textures too (a blurred background)
                continue
            return (normal_size(cols, rows),)
    return ()


def board_size_verdict(stated: Size, seen: Mapping[str, tuple], *, n_searched: int) -> Optional[Size]:
    """The size most searched images show instead of ``stated``, or None when most do not agree on one.

    ``seen``: view id -> sizes seen in that view (:func:`visible_grid_sizes`), over the views where the
    stated size was not found; ``n_searched``: the images searched for the stated board (found or not).
    Another size is named only when it is seen in more than half of the searched images: a few views
    that show one row or column less (the board partly out of view, strongly tilted, or a board edge
    against a dark background read as one more column) never outvote the views where the stated board
    was found. Ties between two other sizes cannot reach a majority each.
    """
    stated = normal_size(*stated)
    counts = Counter(s for sizes in seen.values() for s in set(sizes))
    counts.pop(stated, None)
    if not counts or n_searched <= 0:
        return None
    best, n = max(counts.items(), key=lambda kv: (kv[1], kv[0][0] * kv[0][1]))
    return best if 2 * n > n_searched else None


@dataclass(frozen=True)
class SizeSurvey:
    """The chessboard sizes seen in the images where the stated size was not found."""

    stated: Size  # (cols, rows) as the session states it
    seen: dict  # view id -> tuple of sizes seen there (every image where the stated board was not found)
    n_images: int  # images searched for the stated board (found or not)

    @property
    def counts(self) -> dict:
        """Size -> number of images showing it, most frequent first."""
        c = Counter(s for sizes in self.seen.values() for s in set(sizes))
        return dict(sorted(c.items(), key=lambda kv: (-kv[1], -kv[0][0] * kv[0][1])))

    @property
    def likely_size(self) -> Optional[Size]:
        """The size the views show instead of the stated one (:func:`board_size_verdict`), or None."""
        return board_size_verdict(self.stated, self.seen, n_searched=self.n_images)

    def text(self) -> str:
        """e.g. "no 9x6 chessboard in 20 of 20 images; 11x8 inner corners seen in 18 of 20"."""
        n = self.n_images
        seen = ", ".join(f"{size_text(s)} inner corners seen in {k} of {n}" for s, k in self.counts.items())
        return f"no {self.stated[0]}x{self.stated[1]} chessboard in {len(self.seen)} of {n} images; " + (
            seen or "no other chessboard seen in them"
        )

    def fix(self) -> str:
        """What to change in the session files."""
        size = self.likely_size
        if size is None:
            return (
                f"count the inner corners (where four squares meet) and state them; the session says "
                f"{self.stated[0]}x{self.stated[1]}"
            )
        c, r = size
        return (
            f"the board has {c}x{r} inner corners, not {self.stated[0]}x{self.stated[1]}: fix config.yaml "
            f"checkerboard_args XX: {c}, YY: {r} (or session.yaml target.inner_corners: [{c}, {r}])"
        )


def size_survey(results: Mapping[str, object], stated: Size) -> Optional[SizeSurvey]:
    """The survey recorded on the failures of :func:`handeye.detect.detect_views` (``seen_sizes``).

    ``results``: every searched image's detection or failure. None when no image lacks the stated board.
    """
    seen = {vid: tuple(s) for vid, r in results.items() if (s := getattr(r, "seen_sizes", None)) is not None}
    if not seen:
        return None
    return SizeSurvey(stated=tuple(stated), seen=seen, n_images=len(results))
