"""handeye: robot hand-eye calibration with honest uncertainty.

Frames and transforms follow one rule everywhere (see docs/conventions.md):
``T_a_b`` is the pose of frame ``b`` in frame ``a``, a 4x4 float64 with ``p_a = T_a_b @ p_b``.
"""

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

try:
    __version__ = _version("handeye")
except PackageNotFoundError:  # running from a source checkout that is not installed
    __version__ = "0.0.0+source"

from .errors import HandeyeError  # noqa: E402

__all__ = ["HandeyeError", "__version__"]
