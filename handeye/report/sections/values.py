"""Numbers read from result.json: a value that is absent or not a number reads as NaN."""

from __future__ import annotations


def _num(x) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return float("nan")
