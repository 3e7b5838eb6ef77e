"""Joint refinement of the hand-eye calibration in a GTSAM factor graph.

With noise estimation, outlier decisions and the covariance of the hand-eye transform. Modules:
:mod:`.refinement` (``refine()``), :mod:`.refitting` (``refit()``, one cross-validation fold),
:mod:`.problem` (the factor graph: the only GTSAM user), :mod:`.noise`, :mod:`.outliers` (the
robot-pose test and the decisions), :mod:`.covariance`, :mod:`.robot_model`, :mod:`.poseonly`,
:mod:`.validation`, :mod:`.options` and :mod:`.result`. ``refine`` and ``refit`` load on first use,
so :mod:`.outliers` imports without GTSAM.

See docs/refinement.md.
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
