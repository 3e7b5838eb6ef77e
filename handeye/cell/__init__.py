"""A cell: several cameras of one arm calibrated in one factor graph (``handeye calibrate S1 S2 ...``).

:mod:`.workflow` (:func:`calibrate_cell`, the cell folder's ``cell.yaml``), :mod:`.build` (the joint graph's
inputs from each camera's run, the cell's result.json and its cross-camera checks), :mod:`.report`. The
graph is :mod:`handeye.refine.cell`'s. See docs/refinement.md.
"""

from __future__ import annotations

from .workflow import CellWorkflowResult, calibrate_cell, is_cell_folder, read_cell_file

__all__ = ["CellWorkflowResult", "calibrate_cell", "is_cell_folder", "read_cell_file"]
