"""Numbers in words for people: the reports' and the verdict's one way of printing a value (no template engine)."""

from __future__ import annotations

import math


def num(x, digits: int = 2, *, signed: bool = False) -> str:
    """A number for people: fixed digits, an em dash for missing values (ASCII minus: numbers get copied).

    A value that is not zero but would print as zeros gets two significant digits (0.0034), and below 5e-7
    scientific notation: a sigma of 0.003 mm must not read as 0.00.
    """
    if x is None or isinstance(x, str):
        return "—" if x is None else x
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    if not math.isfinite(v):
        return "—"
    if v != 0 and abs(v) < 0.5 * 10.0**-digits:  # a small value is not zero: two significant digits
        digits = min(-math.floor(math.log10(abs(v))) + 1, 6)
        if abs(v) < 0.5e-6:
            return f"{v:+.1e}" if signed else f"{v:.1e}"
    s = f"{v:+.{digits}f}" if signed else f"{v:.{digits}f}"
    if s.lstrip("+-").strip("0.") == "":  # -0.000 -> 0.000
        s = s.replace("-", "+" if signed else "")
    return s
