"""Two cells compared (``handeye compare CELL_A CELL_B``): each common camera, and each common camera pair.

Each camera both cells hold is compared as two one-camera results are (:func:`.compare.compare_loaded`: the
difference of its X, the Mahalanobis distance under both covariances, the p-value); each camera pair both
hold, ``T_a_b``, is tested the same way under the two pairs' covariances (chi-square, 6 dof). The cell is
drifted when any camera or pair is. See docs/recalibrate.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Union

import numpy as np

from ..errors import InputError
from ..output import plain
from ..stats import wald_p_value
from .compare import ALPHA, Comparison, compare_loaded, comparison_lines, x_difference
from .loaded import load_result


@dataclass(frozen=True)
class CellComparison:
    """Cell B against cell A: ``cameras`` name -> :class:`~.compare.Comparison`, ``pairs`` 'a/b' -> its test."""

    sources: tuple
    cameras: dict
    pairs: dict = field(default_factory=dict)
    only_a: tuple = ()
    only_b: tuple = ()
    alpha: float = ALPHA

    @property
    def drifted(self) -> bool:
        return any(c.drifted for c in self.cameras.values()) or any(p["drifted"] for p in self.pairs.values())

    @property
    def moved(self) -> list[str]:
        """The cameras and pairs beyond their uncertainty, by name."""
        return [n for n, c in self.cameras.items() if c.drifted] + [k for k, p in self.pairs.items() if p["drifted"]]

    def to_dict(self) -> dict:
        return plain(
            {
                "kind": "cell",
                "results": list(self.sources),
                "cameras": {n: c.to_dict() for n, c in self.cameras.items()},
                "camera_pairs": self.pairs,
                "only_in_a": list(self.only_a),
                "only_in_b": list(self.only_b),
                "alpha": self.alpha,
                "drifted": self.drifted,
                "moved": self.moved,
            },
            nan_to_none=True,
        )


def _pair(a: dict, b: dict, alpha: float) -> dict:
    """The test of one camera pair ``T_a_b`` of two cells (the verdict covariance where a cell gives one)."""
    Ta, Tb = np.asarray(a["matrix"], float), np.asarray(b["matrix"], float)
    Ca, Cb = (np.asarray(p.get("cov_6x6_verdict") or p["cov_6x6"], float) for p in (a, b))
    d = x_difference(Ta, Ca, Tb, Cb)
    p = wald_p_value(d["d2"], 6, None)
    keep = ("d_trans_mm", "d_rot_deg", "sigma_trans_mm", "sigma_rot_deg")
    return {
        "name": a["name"],
        **{k: d[k] for k in keep},
        "trans_mm": float(np.linalg.norm(d["d_trans_mm"])),
        "rot_deg": float(np.linalg.norm(d["d_rot_deg"])),
        "mahalanobis2": d["d2"],
        "dof": 6,
        "p_value": p,
        "drifted": bool(p < alpha),
    }


def compare_cells(a: Union[str, Path], b: Union[str, Path], *, alpha: float = ALPHA) -> CellComparison:
    """Cell ``b`` against cell ``a`` (result folders or result.json paths).

    Cameras of different modes or boards are refused in one line naming the camera (InputError
    ``not_comparable``); cells without a camera in common too.
    """
    from ..contract import read_result

    ma, mb = (read_result(Path(p)) for p in (a, b))
    common = [n for n in ma.camera_names if n in mb.camera_names]
    if not common:
        raise InputError(
            "the two cells have no camera in common "
            f"(A: {', '.join(ma.camera_names)}; B: {', '.join(mb.camera_names)})",
            code="not_comparable",
            hint="compare cells of one arm, whose cameras keep their names",
        )
    cams: dict[str, Comparison] = {}
    for n in common:
        c = compare_loaded(load_result(a, camera=n), load_result(b, camera=n), alpha=alpha)
        if not c.comparable:
            raise InputError(
                f"camera {n} of the two cells is not comparable: {c.reason}",
                code="not_comparable",
                hint="compare calibrations of one rig (same mode, board and camera resolution)",
            )
        cams[n] = c
    pa, pb = ma.raw.get("camera_pairs") or {}, mb.raw.get("camera_pairs") or {}
    pairs = {k: _pair(pa[k], pb[k], alpha) for k in pa if k in pb}
    return CellComparison(
        sources=(str(a), str(b)),
        cameras=cams,
        pairs=pairs,
        only_a=tuple(n for n in ma.camera_names if n not in common),
        only_b=tuple(n for n in mb.camera_names if n not in common),
        alpha=alpha,
    )


def cell_comparison_lines(c: CellComparison) -> list[str]:
    """A cell's comparison for a terminal: each camera's table, each pair's line, the cell's verdict."""
    lines: list[str] = []
    for n, cc in c.cameras.items():
        lines += [f"camera {n}:"] + ["  " + s for s in comparison_lines(cc)]
    for k, p in c.pairs.items():
        lines.append(
            f"pair {k}: {p['name']} B - A {p['trans_mm']:.3f} mm, {p['rot_deg']:.4f} deg; Mahalanobis^2 "
            f"{p['mahalanobis2']:.2f} (6 dof), p = {p['p_value']:.3g}: "
            + ("DRIFTED" if p["drifted"] else "same within the uncertainty")
        )
    for which, names in (("A", c.only_a), ("B", c.only_b)):
        if names:
            lines.append(f"only in {which} (not compared): {', '.join(names)}")
    lines.append(
        f"cell: DRIFTED ({', '.join(c.moved)}) at {c.alpha:g}"
        if c.drifted
        else f"cell: every camera and pair the same within the uncertainty at {c.alpha:g}"
    )
    return lines
