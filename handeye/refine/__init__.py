"""Joint refinement of the hand-eye calibration in a GTSAM factor graph, with noise estimation,
outlier decisions and the covariance of the hand-eye transform.

Modules, by concern:

* :mod:`.refinement`  ``refine()``: the stages (start, guard solves, outlier loop, covariance);
* :mod:`.refitting`   ``refit()``: one solve of a result's model on a subset of its views, with its noise
  levels and outlier decisions held (a cross-validation fold);
* :mod:`.problem`     the factor graph, its Values, keys and solver: the ONLY GTSAM user of handeye;
* :mod:`.noise`       the pixel and robot noise levels (robust starts, variance-component estimation);
* :mod:`.outliers`    THE robot-pose outlier test (shared with the diagnostics; pure numpy) and the
  decisions on corners, views and robot poses, with the decide / re-solve loop;
* :mod:`.covariance`  arrow-structured information inverse and the derived forms (sigmas,
  correlations, predicted error at the working distance);
* :mod:`.options` / :mod:`.result`  the inputs (defaults from configs/refine.yaml) and the result.

``refine`` and ``refit`` are imported on first use, so that ``handeye.refine.outliers`` can be imported without
loading GTSAM.
"""

from __future__ import annotations

from typing import Any

from .options import RefineOptions, RefineView
from .outliers import Outlier
from .result import RefineResult

__all__ = ["refine", "refit", "Refit", "RefineOptions", "RefineView", "RefineResult", "Outlier"]


def __getattr__(name: str) -> Any:
    if name == "refine":
        from .refinement import refine

        return refine
    if name in ("refit", "Refit"):
        from . import refitting

        return getattr(refitting, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
