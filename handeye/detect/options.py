"""Detection settings, read from ``configs/detection.yaml`` (``detection:``), where each has its unit
and origin."""
from __future__ import annotations

import functools
from dataclasses import dataclass, fields

import cv2

from ..config import load_preset
from ..errors import ConfigError


@dataclass(frozen=True)
class DetectionOptions:
    min_corners: int  # fewest corners a view needs
    half_size_above_px: int  # chessboards are searched at half size in larger images
    subpix_window_factor: float  # cornerSubPix half window = factor x corner spacing ...
    subpix_window_min_px: int  # ... clipped to [min, max] px
    subpix_window_max_px: int
    charuco_subpix_window_px: int
    subpix_max_iter: int
    subpix_eps_px: float
    order_cue_min_grey: float  # grey-level difference that decides a chessboard's corner order
    origin_dot_ratio: float  # circle grids: size ratio of the origin dot to the others
    sharp_edge_sigma_px: float  # edge width of a sharp image
    saturated_grey: int  # grey level counted as saturated
    thumbnail_width_px: int
    thumbnail_jpeg_quality: int

    @classmethod
    def from_config(cls, cfg: dict) -> "DetectionOptions":
        names = {f.name for f in fields(cls)}
        unknown, missing = set(cfg) - names, names - set(cfg)
        if unknown or missing:
            raise ConfigError("detection settings do not match", path="configs/detection.yaml",
                              expected=", ".join(sorted(names)),
                              received=f"unknown {sorted(unknown)}, missing {sorted(missing)}")
        return cls(**cfg)

    @property
    def subpix_criteria(self) -> tuple:
        return (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, self.subpix_max_iter, self.subpix_eps_px)


@functools.lru_cache(maxsize=None)
def default_options() -> DetectionOptions:
    """The shipped settings (parsed once per process)."""
    return DetectionOptions.from_config(load_preset("detection")["detection"])
