"""Detection settings, read from ``configs/detection.yaml`` (``detection:``).

Each setting has its unit and origin in that file.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2

from ..config import check_section, load_preset


@dataclass(frozen=True)
class CircleBlobOptions:
    """cv2.SimpleBlobDetector settings for circle-grid dots (see configs/detection.yaml)."""

    min_threshold: float
    max_threshold: float
    threshold_step: float
    min_repeatability: int
    min_dist_px: float
    min_area_px2: float
    max_area_px2_at_640x480: float
    min_convexity: float


@dataclass(frozen=True)
class DetectionOptions:
    min_corners: int  # fewest corners a view needs
    half_size_above_px: int  # chessboards are searched at half size in larger images
    search_max_megapixels: float  # larger images are searched on a copy reduced to this area (chessboards) ...
    search_max_megapixels_charuco_circles: float  # ... and this one (ChArUco, circle grids)
    time_budget_s: float  # wall-clock time of one image's detection after which slower searches are skipped
    subpix_window_factor: float  # cornerSubPix half window = factor x the square's size in px ...
    subpix_window_min_px: int  # ... clipped to [min, max] px
    subpix_window_max_px: int
    coarse_outlier_squares: float  # a coarse corner this far (squares) from the board homography restarts there
    grid_check_radius_steps: float  # the geometric check predicts a corner from neighbours this near (grid steps)
    grid_check_max_px: float  # ... and drops or re-detects a view with a corner farther than this from it ...
    grid_check_max_share: float  # ... plus this share of the square's size in px
    subpix_blur_sigma_px: float  # chessboard corners are refined on the image smoothed by this Gaussian
    saddle_window_factor: float  # symmetry fit half window = factor x the square's size in px (clipped as above)
    saddle_shading_box_px: int  # the shading removed before the symmetry fit: a box average this wide
    saddle_iterations: int  # re-centrings of the symmetry fit
    corner_disagreement_max_px: float  # a corner where cornerSubPix and the symmetry fit differ more is not used
    charuco_subpix_window_px: int
    frontal_min_clear_px: float  # AprilGrid and ChArUco corners: refined in the board's frontal frame (.frontal) ...
    frontal_reach_clear: float  # ... on patches reaching this many clear margins around the corner ...
    frontal_window_share: float  # ... with a cornerSubPix half window of this share of the margin
    subpix_max_iter: int
    subpix_eps_px: float
    order_cue_min_grey: float  # grey-level difference that decides a chessboard's corner order
    origin_dot_ratio: float  # circle grids: size ratio of the origin dot to the others
    circle_blobs: CircleBlobOptions
    sharp_edge_sigma_px: float  # edge width of a sharp image
    saturated_grey: int  # grey level counted as saturated
    thumbnail_width_px: int
    thumbnail_jpeg_quality: int
    size_survey_max_side_px: int  # the board-size survey works on images reduced to this longer side

    @classmethod
    def from_config(cls, cfg: dict) -> "DetectionOptions":
        """From the ``detection:`` mapping; a missing or unknown key is a ConfigError naming it."""
        check_section(cls, cfg, name="detection", source="configs/detection.yaml")
        check_section(
            CircleBlobOptions, cfg["circle_blobs"], name="detection.circle_blobs", source="configs/detection.yaml"
        )
        return cls(**dict(cfg, circle_blobs=CircleBlobOptions(**cfg["circle_blobs"])))

    @property
    def subpix_criteria(self) -> tuple:
        return (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, self.subpix_max_iter, self.subpix_eps_px)


@functools.lru_cache(maxsize=None)
def default_options() -> DetectionOptions:
    """The shipped settings (parsed once per process)."""
    return DetectionOptions.from_config(load_preset("detection")["detection"])
