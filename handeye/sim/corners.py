"""Corner-level synthetic sessions: projected corners with known ground truth, no images.

:func:`make_corner_session` samples a rig and view poses (:mod:`handeye.sim.scenarios`), projects
the target's corners through the truth with THE projection
(:func:`handeye.camera.pixels_from_board_points`), adds optional pixel noise, robot pose noise and
gross robot-pose outliers, and returns a frozen :class:`CornerSession`. The same seed and options
give the geometry that :func:`handeye.sim.vendor.write_vendor_session` renders to images.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Union

import numpy as np

from ..camera import Intrinsics, pixels_from_board_points
from ..errors import ConfigError
from ..mounting import mounting
from ..records import Detection
from ..targets import TargetSpec
from .robot_error import (
    DEFAULT_ARM,
    DH_ANGLE_ERROR_DEG,
    DH_LENGTH_ERROR_MM,
    ENCODER_SIGMA_DEG,
    OneConfiguration,
    check_model_name,
    joints_for_poses,
    make_kinematic_error,
    report_poses,
)
from .scenarios import (
    DEFAULT_INTRINSICS,
    DEFAULT_TARGET,
    arm_workspace,
    outlier_offset,
    perturb_T_base_end,
    random_streams,
    sample_hidden_view_pose,
    sample_setup,
    sample_view_poses,
)


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class CornerSession:
    """A synthetic session at corner level, with its ground truth.

    Per view (same order as ``view_ids``; look views up by id with :meth:`index`):
    ``corner_ids`` (n,) ints into ``target.object_points()``, ``image_points`` (n,2) noisy pixels
    (empty for hidden views), ``T_base_end_true`` / ``T_base_end_reported`` (N,4,4).
    ``T_x_true`` is ``T_end_cam`` (eye_in_hand) or ``T_base_cam`` (eye_to_hand); ``T_board_true``
    is ``T_base_board`` or ``T_end_board`` (see ``x_name``/``board_name``).
    ``robot_error`` names the model between true and reported poses (:mod:`handeye.sim.robot_error`):
    ``iid``: reported = true @ dT (end frame) with ``robot_noise`` = (sigma_mm, sigma_deg) per axis;
    ``none``; ``kinematic``: reported = the nominal arm's forward kinematics of the encoder readings
    ``joints_encoder`` (N, 6), the true arm (``robot_model``, a JSON-ready description) being at
    ``joints_true``. A gross error is added on ``outlier_view_ids`` in every model.
    """

    mode: str
    target: TargetSpec
    intrinsics: Intrinsics
    T_x_true: np.ndarray
    T_board_true: np.ndarray
    view_ids: tuple
    corner_ids: tuple
    image_points: tuple
    T_base_end_true: np.ndarray
    T_base_end_reported: np.ndarray
    outlier_view_ids: tuple = ()
    hidden_view_ids: tuple = ()
    noise_px: float = 0.0
    robot_noise: tuple = (0.0, 0.0)
    seed: int = 0
    robot_error: str = "iid"
    joints_true: Optional[np.ndarray] = None  # (N, n) radians, kinematic model only
    joints_encoder: Optional[np.ndarray] = None  # (N, n) radians: what the arm reports
    robot_model: Optional[dict] = None

    @property
    def x_name(self) -> str:
        return mounting(self.mode).x_name

    @property
    def board_name(self) -> str:
        return mounting(self.mode).board_name

    @property
    def n_views(self) -> int:
        return len(self.view_ids)

    def refine_views(self, joints: Optional[np.ndarray] = None, T_reported: Optional[np.ndarray] = None) -> list:
        """Every view as the refinement takes it (:class:`handeye.refine.RefineView`), in view order.

        ``joints`` (N, n): each view's joint readings (e.g. ``joints_encoder``), else none; ``T_reported`` (N,4,4):
        robot poses other than ``T_base_end_reported``.
        """
        from ..refine.options import RefineView

        T = self.T_base_end_reported if T_reported is None else T_reported
        return [
            RefineView(vid, ids, pts, T[k], None if joints is None else joints[k])
            for k, (vid, ids, pts) in enumerate(zip(self.view_ids, self.corner_ids, self.image_points, strict=True))
        ]

    def index(self, view_id: str) -> int:
        try:
            return self.view_ids.index(str(view_id))
        except ValueError:
            raise KeyError(view_id) from None

    @property
    def T_cam_board_true(self) -> np.ndarray:  # (N, 4, 4)
        return mounting(self.mode).predict_T_cam_board(self.T_x_true, self.T_board_true, self.T_base_end_true)

    def detections(self) -> tuple:
        """:class:`handeye.records.Detection` per visible view (hidden views have none)."""
        size = (self.intrinsics.width, self.intrinsics.height)
        return tuple(
            Detection(view_id=vid, corner_ids=ids, image_points=pts, image_size=size)
            for vid, ids, pts in zip(self.view_ids, self.corner_ids, self.image_points, strict=False)
            if len(ids)
        )


def _resolve_view_ids(n_views: int, ids, what: str) -> tuple:
    valid = {str(k) for k in range(1, n_views + 1)}
    out = tuple(str(v) for v in ids)
    bad = [v for v in out if v not in valid]
    if bad:
        raise ConfigError(f"unknown view ids in {what}", expected=f"ids among 1..{n_views}", received=repr(bad))
    if len(set(out)) != len(out):
        raise ConfigError(f"duplicate view ids in {what}", expected="each id once", received=repr(list(out)))
    return tuple(sorted(out, key=int))


def make_corner_session(
    *,
    mode: str = "eye_in_hand",
    n_views: int = 20,
    seed: int = 0,
    target: TargetSpec = DEFAULT_TARGET,
    intrinsics: Optional[Intrinsics] = None,
    noise_px: float = 0.3,
    robot_noise: tuple[float, float] = (0.0, 0.0),
    outlier_views: Union[int, Sequence[str]] = 0,
    hidden_views: Sequence[str] = (),
    outlier_trans_mm: tuple[float, float] = (5.0, 30.0),
    outlier_rot_deg: tuple[float, float] = (2.0, 10.0),
    robot_error: str = "iid",
    arm: str = DEFAULT_ARM,
    encoder_sigma_deg: float = ENCODER_SIGMA_DEG,
    dh_length_error_mm: tuple[float, float] = DH_LENGTH_ERROR_MM,
    dh_angle_error_deg: tuple[float, float] = DH_ANGLE_ERROR_DEG,
    rig: Optional[tuple] = None,
    robot_model_seed: Optional[int] = None,
    **view_options,
) -> CornerSession:
    """A corner-level synthetic session with ground truth (see module docstring for seeding).

    ``noise_px``: Gaussian sigma (px, per coordinate) added to the projected corners.
    ``robot_noise``: (sigma_mm, sigma_deg) per axis on the reported ``T_base_end`` (end frame).
    ``outlier_views``: a count (ids drawn at random among visible views) or explicit ids; those
    views' reported pose gets an extra gross error (``outlier_trans_mm``, ``outlier_rot_deg``).
    ``hidden_views``: ids whose robot pose turns the camera away (no corners, detection fails).
    ``robot_error``: ``iid`` (the ``robot_noise`` above), ``none`` or ``kinematic``: the arm ``arm``
    (a preset of :mod:`handeye.kinematics`) with DH errors drawn from ``dh_length_error_mm`` /
    ``dh_angle_error_deg`` and encoder noise ``encoder_sigma_deg`` per joint
    (:mod:`handeye.sim.robot_error`); the rig is shrunk to the arm's reach
    (:func:`handeye.sim.robot_error.workspace_scale`), the camera-to-board distances with it, and only
    poses the true arm reaches within its joint limits are drawn (in one configuration where the views
    allow). A rig where the arm cannot show the camera the board is drawn again, with any robot error model.
    So a kinematic session's geometry differs from the iid session of the same seed; its robot model comes
    from its own random stream.
    ``view_options`` go to :func:`sample_view_poses` (distance_m, tilt_deg, roll_deg, ...).
    ``rig``: ``(T_x, T_board)`` to use instead of the seed's rig (a later session of one installed rig,
    e.g. with the camera bumped); ``robot_model_seed``: draw the kinematic arm from this seed's stream
    instead of ``seed``'s (the same arm in a later session).
    All corners are projected with :func:`handeye.camera.pixels_from_board_points` through
    ``mounting(mode).predict_T_cam_board(T_x_true, T_board_true, T_base_end_true)``.
    """
    mounting(mode)  # an unknown mode is a ConfigError
    intrinsics = DEFAULT_INTRINSICS if intrinsics is None else intrinsics
    n_views = int(n_views)
    if noise_px < 0 or robot_noise[0] < 0 or robot_noise[1] < 0:
        raise ConfigError(
            "negative noise level",
            expected="noise_px, robot_noise >= 0",
            received=f"noise_px={noise_px}, robot_noise={tuple(robot_noise)}",
        )
    check_model_name(robot_error)
    if robot_error != "iid" and (robot_noise[0] > 0 or robot_noise[1] > 0):
        raise ConfigError(
            f"robot_noise is the iid model's; robot_error is {robot_error!r}",
            expected="robot_noise (0, 0) or robot_error 'iid'",
            received=str(tuple(robot_noise)),
        )
    view_ids = tuple(str(k) for k in range(1, n_views + 1))
    hidden = _resolve_view_ids(n_views, hidden_views, "hidden_views")
    rngs = random_streams(seed)
    visible = [v for v in view_ids if v not in hidden]
    if isinstance(outlier_views, (int, np.integer)):
        if not 0 <= int(outlier_views) <= len(visible):
            raise ConfigError(
                "too many outlier views", expected=f"0..{len(visible)} (visible views)", received=str(outlier_views)
            )
        picked = rngs["outliers"].choice(len(visible), size=int(outlier_views), replace=False)
        outliers = tuple(sorted((visible[i] for i in picked), key=int))
    else:
        outliers = _resolve_view_ids(n_views, outlier_views, "outlier_views")
        if set(outliers) & set(hidden):
            raise ConfigError(
                "a view cannot be both hidden and an outlier",
                expected="disjoint id sets",
                received=repr(sorted(set(outliers) & set(hidden), key=int)),
            )

    geo = rngs["geometry"]
    kin, pose_ok, scale = None, None, 1.0
    if robot_error == "kinematic":
        model_rng = rngs["robot_model"] if robot_model_seed is None else random_streams(robot_model_seed)["robot_model"]
        kin = make_kinematic_error(
            rng=model_rng,
            arm=arm,
            length_error_mm=dh_length_error_mm,
            angle_error_deg=dh_angle_error_deg,
            encoder_sigma_deg=encoder_sigma_deg,
        )
        scale, sized = arm_workspace(arm, mode=mode, target=target)
        pose_ok = OneConfiguration(kin)  # the views of one capture sequence: one arm configuration
        view_options = {**sized, **view_options}  # a distance range given stays
    setup = sample_setup(mode=mode, rng=geo, target=target, workspace_scale=scale)
    T_x, T_board = setup["T_x"], setup["T_board"]
    if rig is not None:
        T_x, T_board = np.asarray(rig[0], float), np.asarray(rig[1], float)
    # a kinematic arm: 4 tries per rig (the first view's configuration, twice another view's, then any
    # configuration per pose); a rig whose camera sees too little of what the arm reaches is drawn again, as
    # is a fixed camera the arm cannot bring the board near enough to (a small target)
    if rig is not None:
        tries = 1 if kin is None else 4
    else:
        tries = 4 if kin is None else 12
    for attempt in range(tries):
        try:
            T_vis = sample_view_poses(
                mode=mode,
                n_views=len(visible),
                rng=geo,
                T_x=T_x,
                T_board=T_board,
                target=target,
                intrinsics=intrinsics,
                pose_ok=pose_ok,
                **view_options,
            )
            break
        except ConfigError:
            if attempt == tries - 1:
                raise
            if kin is None or attempt % 4 == 3:
                setup = sample_setup(mode=mode, rng=geo, target=target, workspace_scale=scale)
                T_x, T_board = setup["T_x"], setup["T_board"]
            if kin is not None:
                pose_ok = OneConfiguration(kin, any_configuration=attempt % 4 == 2)
    T_true = np.empty((n_views, 4, 4))
    it = iter(T_vis)
    hid_rng = rngs["hidden"]
    for k, vid in enumerate(view_ids):
        if vid in hidden:
            T_true[k] = sample_hidden_view_pose(
                mode=mode,
                rng=hid_rng,
                T_x=T_x,
                T_board=T_board,
                target=target,
                intrinsics=intrinsics,
                pose_ok=pose_ok,
                draw_pose=None if pose_ok is None else pose_ok.draw_pose,
            )
        else:
            T_true[k] = next(it)

    q_true = q_enc = None
    if kin is not None:
        q_true = joints_for_poses(kin, T_true, configuration=pose_ok)
        q_enc, T_rep = report_poses(kin, q_true, rng=rngs["robot_noise"])
    else:
        T_rep = perturb_T_base_end(
            T_true, rng=rngs["robot_noise"], sigma_mm=float(robot_noise[0]), sigma_deg=float(robot_noise[1])
        )
    out_rng = rngs["outliers"]
    for vid in outliers:
        k = view_ids.index(vid)
        T_rep[k] = T_rep[k] @ outlier_offset(out_rng, trans_mm=outlier_trans_mm, rot_deg=outlier_rot_deg)

    T_cam_board = mounting(mode).predict_T_cam_board(T_x, T_board, T_true)
    obj = target.object_points()
    all_ids = np.arange(target.n_corners)
    px_rng = rngs["pixel_noise"]
    ids_out, pts_out = [], []
    for k, vid in enumerate(view_ids):
        if vid in hidden:
            ids_out.append(_frozen(np.zeros(0, dtype=int)))
            pts_out.append(_frozen(np.zeros((0, 2))))
            continue
        uv = pixels_from_board_points(T_cam_board[k], obj, intrinsics)
        uv = uv + px_rng.normal(0.0, float(noise_px), size=uv.shape) if noise_px > 0 else uv
        ids_out.append(_frozen(all_ids))
        pts_out.append(_frozen(uv))
    return CornerSession(
        mode=mode,
        target=target,
        intrinsics=intrinsics,
        T_x_true=_frozen(T_x),
        T_board_true=_frozen(T_board),
        view_ids=view_ids,
        corner_ids=tuple(ids_out),
        image_points=tuple(pts_out),
        T_base_end_true=_frozen(T_true),
        T_base_end_reported=_frozen(T_rep),
        outlier_view_ids=outliers,
        hidden_view_ids=hidden,
        noise_px=float(noise_px),
        robot_noise=(float(robot_noise[0]), float(robot_noise[1])),
        seed=int(seed),
        robot_error=robot_error,
        joints_true=None if q_true is None else _frozen(q_true),
        joints_encoder=None if q_enc is None else _frozen(q_enc),
        robot_model=None if kin is None else kin.describe(),
    )
