"""handeye: robot hand-eye calibration with honest uncertainty.

Frames and transforms follow one rule everywhere (see docs/conventions.md):
``T_a_b`` is the pose of frame ``b`` in frame ``a``, a 4x4 float64 with ``p_a = T_a_b @ p_b``.
"""

from .errors import HandeyeError

__all__ = ["HandeyeError", "__version__"]


def __getattr__(name: str) -> str:
    """``__version__``, read from the installed package's metadata on first use.

    importlib.metadata costs about 13 ms of CPU to import, which ``handeye --help`` and the commands that
    never print a version need not pay.
    """
    if name != "__version__":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    from importlib.metadata import PackageNotFoundError, version

    try:
        value = version("handeye")
    except PackageNotFoundError:  # running from a source checkout that is not installed
        value = "0.0.0+source"
    globals()["__version__"] = value
    return value
