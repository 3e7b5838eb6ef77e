"""Gauss-Newton in numpy for the refinement's Gaussian solves that start near their optimum.

A refit (:mod:`.refitting`) starts at the full solution, and each solve of the variance-component loop
(:func:`.noise.solve_with_vce`) at the one before it: a few Gauss-Newton steps on the arrow-shaped
information (:func:`.covariance.arrow_solve`) reach the optimum, each from one vectorised linearisation
of the reprojections (:meth:`.state.ProblemState.reprojection_blocks`) and GTSAM's of the priors
(:meth:`.problem.Problem.prior_blocks`). The steps end when the last is below ``solver.gauss_newton_step_tol``
of every unknown's own sigma; a step that raises the cost or steps that do not settle raise
:class:`NoGaussNewton`, and :func:`solve_gaussian` then solves by Levenberg-Marquardt from the start.

See docs/refinement.md.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Optional

import numpy as np

from .covariance import N_POSES, arrow_solve
from .options import refine_preset

if TYPE_CHECKING:
    from .problem import Problem
    from .state import ReprojectionBlocks


log = logging.getLogger(__name__)


class NoGaussNewton(Exception):
    """The Gauss-Newton steps did not settle (a step raised the cost, or too many steps)."""


def gauss_newton(pb: "Problem", *, start: Optional["ReprojectionBlocks"] = None) -> tuple[np.ndarray, int]:
    """Gauss-Newton steps of ``pb``'s Gaussian problem (no robust loss) from its current estimate, in place.

    ``start``: the reprojection blocks of ``pb.active()`` at the current estimate, when already known (the
    refits' shared linearisation). Returns (the core covariance (c,c) of the last linearisation, the number of
    steps). Raises NoGaussNewton, or LinAlgError when the information is not positive definite.
    """
    cfg = refine_preset()["solver"]
    tol, max_steps = float(cfg["gauss_newton_step_tol"]), int(cfg["gauss_newton_max_steps"])
    idx = pb.active()
    robot = [j for j, i in enumerate(idx) if pb.has_robot_var(i)]
    rv = [idx[j] for j in robot]
    cp, c, w = N_POSES + pb.free.size, pb.n_core, 1.0 / pb.sigma_px**2
    cost_before = np.inf
    for step in range(max_steps):
        b = start if step == 0 and start is not None else pb.reprojection_blocks(idx)
        Hcc, Hcp, Hpp, grad, cost = pb.prior_blocks(rv)
        Hcc[:cp, :cp] += w * b.Hcc.sum(axis=0)
        Hcp[:, :cp] += w * b.Hcp[robot]
        Hpp += w * b.Hpp[robot]
        grad[:cp] += w * b.gc.sum(axis=0)
        grad[c:] += w * b.gp[robot].reshape(-1)
        cost += 0.5 * w * float(b.rr.sum())
        if cost > cost_before * (1.0 + 1e-9):  # more than rounding: the step overshot
            raise NoGaussNewton(f"step {step} raised the cost from {cost_before:.6g} to {cost:.6g}")
        cost_before = cost
        S_cc, S_pp, dx = arrow_solve(Hcc, Hcp, Hpp, -grad)
        pb.apply_step(rv, dx)
        sd = np.sqrt(np.r_[np.diag(S_cc), np.diagonal(S_pp, axis1=1, axis2=2).reshape(-1)])
        if np.all(np.abs(dx) <= tol * sd):
            return S_cc, step + 1
    raise NoGaussNewton(f"the steps did not settle in {max_steps}")


def solve_gaussian(pb: "Problem") -> None:
    """The Gaussian solve of ``pb`` in place: :func:`gauss_newton`, else Levenberg-Marquardt from the same start."""
    state = (pb.T_x.copy(), pb.T_board.copy(), pb.k.copy(), pb.dh.copy(), pb.P.copy())
    try:
        _, steps = gauss_newton(pb)
        pb.iterations += steps
    except (NoGaussNewton, np.linalg.LinAlgError) as e:
        log.debug("Gaussian solve by Levenberg-Marquardt (%s)", e)
        pb.T_x, pb.T_board, pb.k, pb.dh, pb.P = state
        pb.solve(robust=False)
