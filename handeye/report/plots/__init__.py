"""The report's figures: each function draws one figure from plain numpy arrays and returns PNG bytes.

:mod:`.residuals` draws the residual and image-coverage figures, :mod:`.geometry` the pose, rotation
and translation-uncertainty figures, both with the style and helpers of :mod:`.canvas`. matplotlib is
imported when the figures' style is entered (never with the CLI or the pipeline). Nothing here reads files.
"""

from __future__ import annotations

from .canvas import AMBER, AXIS_RGB, DPI, GRID, INK, MUTED, NAVY, ORANGE, RED, SKY, TEAL, WIDTH_IN, style
from .geometry import poses_3d, rotation_coverage, transform, translation_uncertainty
from .residuals import image_coverage, per_view_bars, residual_histogram

__all__ = [
    "AMBER",
    "AXIS_RGB",
    "DPI",
    "GRID",
    "INK",
    "MUTED",
    "NAVY",
    "ORANGE",
    "RED",
    "SKY",
    "TEAL",
    "WIDTH_IN",
    "image_coverage",
    "per_view_bars",
    "poses_3d",
    "residual_histogram",
    "rotation_coverage",
    "style",
    "transform",
    "translation_uncertainty",
]
