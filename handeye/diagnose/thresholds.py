"""The diagnostics' thresholds, read once from configs/diagnostics.yaml (units and origins are there).

:func:`thresholds` returns the shipped values; every check takes its numbers from it, so a site
can tune them in one file and the docs can point at one place.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields

from ..config import check_section, load_preset
from ..errors import ConfigError


def _section(cls, cfg: dict, name: str):
    d = check_section(cls, cfg.get(name), name=name, source="configs/diagnostics.yaml")
    out = {}
    for f in fields(cls):
        try:
            out[f.name] = int(d[f.name]) if f.type == "int" else float(d[f.name])
        except (TypeError, ValueError):
            raise ConfigError(
                f"diagnostics preset: {name}.{f.name} is not a number", expected=str(f.type), received=repr(d[f.name])
            ) from None
    return cls(**out)


@dataclass(frozen=True)
class Readings:
    cost_deg: float
    cost_mm: float
    bad_cost: float
    good_cost: float
    ratio: float
    max_rotation_readings: int


@dataclass(frozen=True)
class Pairing:
    max_shift: int
    min_shift_share: float
    max_swap_candidates: int


@dataclass(frozen=True)
class Scale:
    p_value: float
    min_scatter_gain: float


@dataclass(frozen=True)
class Mode:
    ratio: float
    good_cost: float


@dataclass(frozen=True)
class Views:
    min_fail: int
    min_warn: int
    recommended: int


@dataclass(frozen=True)
class Motion:
    warn_rotation_deg: float
    warn_axis_spread_deg: float


@dataclass(frozen=True)
class RobotPose:
    inlier_factor: float
    noise_floor_deg: float
    noise_floor_mm: float
    pixel_sigma_floor_px: float
    flip_agreement_ratio: float
    size_ratio: float


@dataclass(frozen=True)
class BoardMoved:
    min_segment: int
    p_value: float
    gain: float
    min_gain: float
    min_step_deg: float
    min_step_mm: float
    within_factor: float


@dataclass(frozen=True)
class Detection:
    partial_share: float
    warn_share: float
    low_contrast_grey: float
    min_depth_m: float


@dataclass(frozen=True)
class IntrinsicsChecks:
    dist_info_px: float
    dist_warn_px: float
    dist_warn_shift_px: float
    dist_rms_ratio: float
    mismatch_ratio: float
    mismatch_px: float


@dataclass(frozen=True)
class Images:
    blur_warn_px: float
    blur_warn_square_share: float
    blur_outlier_ratio: float
    blur_outlier_px: float
    sharp_blur_floor_px: float
    overexposed_warn_share: float
    overexposed_info_share: float
    washed_out_black_grey: float
    coverage_warn_share: float


@dataclass(frozen=True)
class CrossValidation:
    loo_max_views: int
    folds: int
    loo_max_views_refined: int
    folds_refined: int
    min_views: int


@dataclass(frozen=True)
class Thresholds:
    readings: Readings
    pairing: Pairing
    views: Views
    motion: Motion
    robot_pose: RobotPose
    board_moved: BoardMoved
    detection: Detection
    intrinsics: IntrinsicsChecks
    images: Images
    cross_validation: CrossValidation
    scale: Scale
    mode: Mode

    @staticmethod
    def from_config(cfg: dict) -> "Thresholds":
        return Thresholds(**{f.name: _section(f.type_cls, cfg, f.name) for f in _SECTIONS})

    def cost(self, rot_deg, trans_mm):
        """A fit's cost: hypot(board scatter / cost_deg, / cost_mm) (elementwise)."""
        import numpy as np

        return np.hypot(np.asarray(rot_deg) / self.readings.cost_deg, np.asarray(trans_mm) / self.readings.cost_mm)


@dataclass(frozen=True)
class _Sec:
    name: str
    type_cls: type


_SECTIONS = tuple(
    _Sec(f.name, c)
    for f, c in zip(
        fields(Thresholds),
        (
            Readings,
            Pairing,
            Views,
            Motion,
            RobotPose,
            BoardMoved,
            Detection,
            IntrinsicsChecks,
            Images,
            CrossValidation,
            Scale,
            Mode,
        ),
        strict=False,
    )
)


@functools.lru_cache(maxsize=1)
def thresholds() -> Thresholds:
    """The shipped thresholds (configs/diagnostics.yaml), parsed and validated once."""
    return Thresholds.from_config(load_preset("diagnostics"))
