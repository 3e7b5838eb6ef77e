"""The command line's number arguments: argparse types that take a number within its range, or refuse it.

A refused value is argparse's one error line ("argument --seed: expected a whole number >= 0, got '-1'"),
exit code 2, before any work. nan and inf are never in range.
"""

from __future__ import annotations

import argparse
import math
from typing import Callable, Optional, Union

Number = Union[int, float]


def number_type(
    cast: Callable[[str], Number],
    expected: str,
    *,
    low: Optional[float] = None,
    high: Optional[float] = None,
    low_open: bool = False,
) -> Callable[[str], Number]:
    """An argparse type: ``cast(text)`` when finite and within [``low``, ``high``] (``low_open``: above ``low``)."""

    def parse(text: str) -> Number:
        try:
            v = cast(text)
        except ValueError:
            v = math.nan
        ok = math.isfinite(v) and (low is None or (v > low if low_open else v >= low)) and (high is None or v <= high)
        if not ok:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return v

    return parse


#: the largest blur sigma (px) the simulators take: past it no board is left to see, and a far larger one
#: exhausts the memory of OpenCV's Gaussian kernel
MAX_BLUR_PX = 100.0

#: ``--workers``, counts
positive_int = number_type(int, "a whole number >= 1", low=1)
#: sigmas
positive_float = number_type(float, "a finite number > 0", low=0, low_open=True)
#: coordinates (``handeye apply``)
finite_float = number_type(float, "a finite number")
#: the simulators' noise levels and bumps
non_negative_float = number_type(float, "a finite number >= 0", low=0)
#: a random seed (numpy's seeds; ``--seed`` of simulate, demo, collect)
seed_int = number_type(int, "a whole number >= 0", low=0)
#: a Gaussian blur sigma in pixels (``--blur``, ``--sim-blur``)
blur_px = number_type(float, f"a blur sigma of 0-{MAX_BLUR_PX:g} px", low=0, high=MAX_BLUR_PX)
#: the largest tone curve the simulators take (grey = 255 (light / 255) ** (1 / gamma)): cameras encode 1.8-2.6
MAX_GAMMA = 4.0
#: a camera's tone curve (``--gamma``): 1 is grey proportional to light, sRGB about 2.2
gamma_value = number_type(float, f"a gamma of 0.25-{MAX_GAMMA:g}", low=0.25, high=MAX_GAMMA)
#: anti-aliasing samples per pixel and axis (``handeye.sim.render``'s range)
supersample_int = number_type(int, "a whole number of samples 1-16", low=1, high=16)
#: the demo's views: one is rendered without the board, and calibrate needs 3
demo_views = number_type(int, "a whole number >= 4 (one view is rendered without the board; calibrate needs 3)", low=4)
