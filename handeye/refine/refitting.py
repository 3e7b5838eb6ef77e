"""refit(): the refinement's solution on a subset of its views, one cross-validation fold.

A refit is ONE Gaussian solve of the refinement's model, started from the full solution, with the
full run's noise levels (pixel, robot, encoder, DH prior scale) and outlier decisions held, so a fold
measures how the estimate moves without some views, not how noise estimation and outlier decisions
would redo themselves on fewer data. :class:`Refitter` solves many folds of one result: each view's
reprojections are linearised once at the full solution and every fold's first Gauss-Newton step is
summed from them; the steps after it re-linearise the fold's views in numpy, until the last step is a
negligible share of every sigma (:mod:`.gauss_newton`), else Levenberg-Marquardt solves the fold.

See docs/refinement.md.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Optional, Sequence

import numpy as np

from ..camera import Intrinsics
from ..errors import InputError
from .covariance import N_POSES
from .gauss_newton import NoGaussNewton, gauss_newton
from .options import RefineView, check_inputs
from .result import RefineResult
from .state import ReprojectionBlocks

if TYPE_CHECKING:
    from .problem import Problem

log = logging.getLogger(__name__)

# robot sigmas of a held noise model are at least this [mm, deg]: a frozen sigma of 0 would make the
# prior a hard constraint (GTSAM treats sigmas below ~1e-9 as such); numerical, far below any robot
ROBOT_SIGMA_MIN_MM = 1e-6
ROBOT_SIGMA_MIN_DEG = 1e-6


@dataclass(frozen=True)
class Refit:
    """Outcome of :func:`refit`."""

    status: str  # ok | failed
    failure_reason: str
    T_x: Optional[np.ndarray]  # (4,4) the result's transform (T_end_cam / T_base_cam), None when failed
    T_board: Optional[np.ndarray]  # (4,4) (T_base_board / T_end_board)
    intrinsics: Optional[Intrinsics]
    view_ids: tuple[Any, ...]  # the views of the solve
    cov_x: Optional[np.ndarray] = None  # (6,6) the refit's model covariance of T_x (the tangent of cov_x_6x6)
    cov_intrinsics: Optional[np.ndarray] = None  # (k,k) of the free intrinsics (the refinement's order)


def refit(
    result: RefineResult, *, object_points: np.ndarray, views: Sequence[RefineView], covariance: bool = True
) -> Refit:
    """Solve the refinement of ``result`` again on ``views`` alone.

    Solve the refinement of ``result`` again on ``views`` alone (a subset of its views), holding its
    noise levels and outlier decisions (see the module docstring).

    ``object_points`` (N,3): the board points the views' ``corner_ids`` index (the same as for
    :func:`handeye.refine.refine`). Raises InputError for a view the full run did not have or dropped,
    or for fewer than 3 views; a solve that fails returns ``status="failed"`` with the reason.
    ``covariance``: also the refit's marginal covariance of T_x and the free intrinsics (``cov_x``,
    ``cov_intrinsics``; None when the information matrix cannot be inverted).
    """
    return Refitter(result, object_points=object_points, views=views).refit(views, covariance=covariance)


class Refitter:
    """Refits of one refinement on subsets of ``views``, sharing the linearisation at the full solution.

    ``views``: the refinement's views the subsets come from (checked as :func:`refit` checks them; the
    corners the refinement flagged are left out). See the module docstring.
    """

    def __init__(self, result: RefineResult, *, object_points: np.ndarray, views: Sequence[RefineView]):
        if result.status != "ok":
            raise InputError(
                "refit needs a successful refinement",
                received=f"status {result.status!r}",
                hint="refit only results with status 'ok'",
            )
        flagged: dict[str, Any] = {}
        for o in result.outliers:
            if o.kind == "corners":
                flagged.setdefault(o.view_id, set()).update(int(c) for c in o.corner_ids)
        self.views: dict[Any, RefineView] = {}
        joints = result.robot_model.get("joint_angles_rad") or {}  # a kinematic model's joint angles per view
        for v in views:
            st = result.per_view.get(v.view_id, {}).get("status")
            if st not in ("used", "robot_excluded"):
                raise InputError(
                    f"view {v.view_id} cannot be refitted",
                    expected="a view the refinement used",
                    received="not in the refinement" if st is None else f"status {st!r}",
                    hint="refit a subset of result.per_view's used views",
                )
            cid = np.asarray(v.corner_ids, int)
            keep = np.array([int(c) not in flagged.get(v.view_id, ()) for c in cid], bool)
            self.views[v.view_id] = RefineView(
                v.view_id,
                cid[keep],
                np.asarray(v.image_points, float).reshape(-1, 2)[keep],
                v.T_base_end,
                v.joint_angles if v.joint_angles is not None else joints.get(v.view_id),
            )
        self.result = result
        # the views checked once (InputError for a damaged one); each refit takes its reported poses from here
        self.object_points, reported = check_inputs(object_points, list(self.views.values()))
        self.reported = dict(zip(self.views, reported, strict=True))
        o0 = result.options
        opts = replace(
            o0,
            robot_noise="none" if o0.robot_noise == "none" else "fixed",
            robot_sigma_mm=max(result.robot_sigma_mm, ROBOT_SIGMA_MIN_MM),
            robot_sigma_deg=max(result.robot_sigma_deg, ROBOT_SIGMA_MIN_DEG),
            outlier_loop=False,
            loss="none",
        )
        if result.robot_model.get("encoder_sigma_deg"):  # the kinematic models' estimated encoder noise, held
            enc = max(float(result.robot_model["encoder_sigma_deg"]), ROBOT_SIGMA_MIN_DEG)
            opts = replace(opts, encoder_sigma_deg=enc)
        sd = result.robot_model.get("dh_prior_sigma") or {}
        if result.robot_model.get("dh_prior_scale", 1.0) != 1.0:  # the arm's DH prior as widened by the full run, held
            opts = replace(opts, dh_sigma_mm=float(sd["length_mm"]), dh_sigma_deg=float(sd["angle_deg"]))
        self.options = opts
        # per view id: its reprojection blocks (ReprojectionBlocks fields, one view) at the full solution
        self._shared: dict[Any, tuple[np.ndarray, ...]] = {}

    def refit(self, views: Sequence[RefineView], *, covariance: bool = True) -> Refit:
        """:func:`refit` on ``views`` (views of the refitter's, by id; InputError for another)."""
        for v in views:
            if v.view_id not in self.views:
                raise InputError(
                    f"view {v.view_id} cannot be refitted",
                    expected="one of the views the refits share",
                    received=f"view {v.view_id}",
                    hint="refit a subset of the views the Refitter was made with",
                )
        kept = [self.views[v.view_id] for v in views]
        ids = tuple(v.view_id for v in kept)
        try:
            pb = self._problem(kept)
            try:
                S_cc: Optional[np.ndarray] = gauss_newton(pb, start=self._start_blocks(pb))[0]
            except (NoGaussNewton, np.linalg.LinAlgError) as e:
                log.debug("refit on views %s: Levenberg-Marquardt (%s)", list(ids), e)
                pb = self._problem(kept)
                g, values, robot_keys = pb.solve(robust=False)
                S_cc = None
        except (RuntimeError, np.linalg.LinAlgError) as e:  # GTSAM raises RuntimeError (indeterminant system)
            log.info("refit on views %s not solved: %s", list(ids), e)
            return Refit("failed", str(e), None, None, None, ids)
        cov_x = cov_k = None
        if covariance:  # the refit's own model covariance: how much less the fold knows than the full run
            try:
                if S_cc is None:
                    S_cc, _ = pb.covariances(g, values, robot_keys)
                k = slice(N_POSES, N_POSES + pb.free.size)
                cov_x = 0.5 * (S_cc[:6, :6] + S_cc[:6, :6].T)
                cov_k = 0.5 * (S_cc[k, k] + S_cc[k, k].T) if pb.free.size else None
            except (RuntimeError, np.linalg.LinAlgError) as e:
                log.info("refit on views %s: no covariance (%s)", list(ids), e)
        intr = Intrinsics.from_vector(pb.k, pb.width, pb.height)
        return Refit("ok", "", pb.T_x.copy(), pb.T_board.copy(), intr, ids, cov_x, cov_k)

    def _problem(self, kept: list[RefineView]) -> "Problem":
        """The refit's problem on ``kept``, at the full solution with the full run's noise levels."""
        from .problem import Problem  # GTSAM on first use

        result = self.result
        if len({v.view_id for v in kept}) != len(kept) or len(kept) < 3:
            check_inputs(self.object_points, kept)  # raises the InputError that says what is wrong
        reported = np.stack([self.reported[v.view_id] for v in kept])
        pb = Problem(
            mode=result.mode,
            object_points=self.object_points,
            views=kept,
            reported=reported,
            intrinsics=result.intrinsics,
            T_x0=result.T_x,
            T_board0=result.T_board,
            options=self.options,
        )
        pb.sigma_px = float(result.sigma_px)
        for i, v in enumerate(kept):
            if result.per_view[v.view_id]["status"] == "robot_excluded":
                pb.status[i] = "robot_excluded"
            if v.view_id in result.robot_poses:
                pb.P[i] = np.asarray(result.robot_poses[v.view_id], float)
        dh = (result.cov_x_intrinsics or {}).get("dh_offsets")
        if dh is not None and np.size(dh) == pb.m_dh:  # the full run's DH offsets, where it reports them
            pb.dh = np.asarray(dh, float).copy()
        return pb

    def _start_blocks(self, pb: "Problem") -> ReprojectionBlocks:
        """The reprojection blocks of ``pb.active()`` at the full solution, each view's computed once."""
        idx = pb.active()
        missing = [i for i in idx if pb.ids[i] not in self._shared]
        if missing:
            b = pb.reprojection_blocks(missing)
            for j, i in enumerate(missing):
                self._shared[pb.ids[i]] = (b.Hcc[j], b.Hcp[j], b.Hpp[j], b.gc[j], b.gp[j], b.rr[j])
        return ReprojectionBlocks(*(np.stack(a) for a in zip(*(self._shared[pb.ids[i]] for i in idx), strict=True)))
