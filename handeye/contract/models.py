"""The models of handeye's files: result.json, observations.json, verify.json and batch.json.

Each model names the fields other commands read, with their type, range and meaning; every other field
is kept as written (``extra="allow"``: a newer writer's additions stay readable). A mapping that only
a report shows (diagnostics, qa, provenance) is checked to be a mapping. The typed accessors of
:class:`Result` (``T_x``, ``x_name``, ``cov_x``, ``intrinsics``) are what the recalibration, export and
apply read.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal, Optional

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    StrictBool,
    StrictInt,
    StrictStr,
    StringConstraints,
    ValidationInfo,
    model_validator,
)

from ..mounting import MODES, mounting
from .fields import (
    Count,
    Cov6,
    Covariance,
    Finite,
    ImageSize,
    Matrix,
    Number,
    Positive,
    Rigid,
    Sigma,
    Vec3,
    Vec4,
    ViewId,
    damaged,
)

#: result.json's version (its ``handeye_result`` key); the oldest version this handeye reads (older ones
#: are migrated by :data:`handeye.contract.MIGRATIONS` or refused)
RESULT_VERSION = 1
OLDEST_RESULT_VERSION = 1
OBSERVATIONS_VERSION = 1
VERIFY_VERSION = 1

VerdictName = Literal["PASS", "WARN", "FAIL", "REFUSED"]
XName = Literal["T_end_cam", "T_base_cam"]
BoardName = Literal["T_base_board", "T_end_board"]
IntrinsicName = Literal["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"]
Mapping = dict[str, Any]


class Open(BaseModel):
    """A block whose known fields are checked and whose other fields are kept as written."""

    # defer_build: a model's validator is built on its first use, so a command builds only the models of the
    # files it reads or writes, and Result (which refers to later models) is built once, not tried first
    model_config = ConfigDict(extra="allow", frozen=False, validate_default=False, defer_build=True)


# ------------------------------------------------------------------------------------------ result.json
def _same_pose(forms: "PoseForms", T_list: list, block: str, name: str) -> None:
    """``block``'s matrix and translation (the forms people read) are ``T``'s (the matrix programs read)."""
    T = np.asarray(T_list, float)
    if forms.matrix is not None and not np.allclose(forms.matrix, T, rtol=0, atol=1e-9):
        raise damaged(f"differs from {name}", f"the same matrix as {name}", f"{block}.matrix")
    if forms.translation_mm is not None and not np.allclose(forms.translation_mm, T[:3, 3] * 1e3, rtol=1e-9, atol=1e-6):
        raise damaged(f"differs from {name}'s translation", f"{name}[:3, 3] in mm", f"{block}.translation_mm")


class PoseForms(Open):
    """``hand_eye`` / ``board``: the transform's name and the same pose in other forms (for people)."""

    name: Optional[StrictStr] = None
    matrix: Optional[Rigid] = None
    translation_mm: Optional[Vec3] = None
    rotvec_deg: Optional[Vec3] = None
    rotvec_rad: Optional[Vec3] = None
    quaternion_wxyz: Optional[Vec4] = None


class Distortion(Open):
    """OpenCV's 5-coefficient distortion (``dist_order`` k1, k2, p1, p2, k3)."""

    k1: Optional[Finite] = None
    k2: Optional[Finite] = None
    p1: Optional[Finite] = None
    p2: Optional[Finite] = None
    k3: Optional[Finite] = None


class IntrinsicsBlock(Open):
    """``intrinsics``: the camera model the result was calibrated with (pixels)."""

    model: Optional[StrictStr] = None
    fx: Positive
    fy: Positive
    cx: Finite
    cy: Finite
    dist: Optional[Distortion] = None
    image_size: Optional[ImageSize] = None
    source: Optional[StrictStr] = None
    calibrate_camera_rms_px: Optional[Sigma] = None

    def to_intrinsics(self):
        """The :class:`handeye.camera.Intrinsics` (missing distortion terms 0, missing image size 0 x 0)."""
        from ..camera import DIST_NAMES, Intrinsics

        dist = self.dist.model_dump() if self.dist is not None else {}
        w, h = self.image_size or (0, 0)
        return Intrinsics(
            self.fx, self.fy, self.cx, self.cy, tuple(float(dist.get(k) or 0.0) for k in DIST_NAMES), int(w), int(h)
        )


class JointCovariance(Open):
    """``refinement.cov_x_intrinsics``: X's tangent and the free intrinsics, jointly.

    With a kinematic robot model, the DH offsets too.
    """

    intrinsics: list[IntrinsicName]
    cross_6xk: Matrix
    intrinsics_kxk: Covariance
    cross_board_6xk: Optional[Matrix] = None
    dh_offsets: Optional[list[Finite]] = None
    cross_6xm: Optional[Matrix] = None
    cross_kxm: Optional[Matrix] = None
    dh_mxm: Optional[Covariance] = None

    @model_validator(mode="after")
    def _shapes(self):
        k = len(self.intrinsics)
        m = len(self.dh_offsets or ())
        shapes = {
            "cross_6xk": (6, k),
            "intrinsics_kxk": (k, k),
            "cross_board_6xk": (6, k),
            "cross_6xm": (6, m),
            "cross_kxm": (k, m),
            "dh_mxm": (m, m),
        }
        for key, shape in shapes.items():
            v = getattr(self, key)
            if v is not None and (len(v), len(v[0]) if v else 0) != shape:
                raise damaged(
                    f"has shape {len(v)}x{len(v[0]) if v else 0}",
                    f"{shape[0]}x{shape[1]} ({k} intrinsics, {m} DH offsets)",
                    field=f"refinement.cov_x_intrinsics.{key}",
                )
        return self


class TrackerScale(Open):
    """``refinement.tracker_scale``: a pose-only session's tracker translation scale, estimated (``--estimate-scale``).

    The tracker's translations are ``value`` x the true ones; ``sigma`` its 1-sigma (with the tracker sigmas'
    degrees of freedom, as X's covariance).
    """

    value: Positive
    sigma: Optional[Sigma] = None


class RobotAccuracy(Open):
    """``refinement.robot_accuracy``: the arm's stated accuracy (handeye.refine.arm_accuracy).

    The flange pose's error per axis, constant over the workspace (``sigma_mm``, ``sigma_deg``), which the data
    cannot show; ``cov_x_6x6`` is its covariance in X's tangent, included in ``cov_x_6x6_verdict``.
    """

    sigma_mm: Sigma
    sigma_deg: Sigma
    frame: Optional[StrictStr] = None
    cov_x_6x6: Cov6
    in_verdict: StrictBool = True


class ViewPoseTest(Open):
    """``view_poses.test``: one robot pose per view against one per camera view (F test, cell_checks)."""

    statistic: Sigma
    dof: list[Count] = Field(description="numerator (6 per extra camera of a view) and denominator")
    p_value: Sigma
    alpha: Sigma
    contradicted: StrictBool


class ViewPoses(Open):
    """``refinement.view_poses`` of a cell: each camera's own pose of a view several cameras see.

    Estimated (``estimated``) when the test rejects one shared pose per view: each camera's pose of such a view
    is the shared one times ``Exp(delta)``, ``delta`` ~ N(0, diag(sigma_rot^2 I, sigma_trans^2 I)) in the end
    frame, the sigmas variance components of the cell; ``rms_*``: the estimated deviations' RMS per axis.
    """

    test: ViewPoseTest
    estimated: StrictBool
    sigma_rot_deg: Optional[Sigma] = None
    sigma_trans_mm: Optional[Sigma] = None
    camera_views: Optional[Count] = None
    rms_rot_deg: Optional[Sigma] = None
    rms_trans_mm: Optional[Sigma] = None


class Refinement(Open):
    """``refinement``: the joint refinement's estimate, noise levels and covariances."""

    status: Optional[StrictStr] = None
    mode: Optional[StrictStr] = None
    x_name: Optional[XName] = None
    cov_x_6x6: Optional[Cov6] = None
    cov_x_6x6_verdict: Optional[Cov6] = None
    cov_x_6x6_validated: Optional[Cov6] = None
    cov_board_6x6: Optional[Cov6] = None
    cov_parametrisation: Optional[StrictStr] = None
    cov_x_intrinsics: Optional[JointCovariance] = None
    intrinsics_cov_names: Optional[list[IntrinsicName]] = None
    cov_intrinsics_verdict: Optional[Covariance] = None
    intrinsics_sigma: Optional[dict[IntrinsicName, Optional[Sigma]]] = None
    intrinsics_sigma_verdict: Optional[dict[IntrinsicName, Optional[Sigma]]] = None
    sigma_px: Optional[Sigma] = None
    robot_sigma_mm: Optional[Sigma] = None
    robot_sigma_deg: Optional[Sigma] = None
    robot_noise_dof: Optional[dict[str, Optional[Number]]] = None
    # pose-only: each estimated tracker sigma's degrees of freedom; the factor X's plug-in covariance was multiplied
    # by for the estimated sigmas (image or pose-only: handeye.refine.result, handeye.refine.tracker_dof; 1 when
    # none was estimated), the F's degrees of freedom with its 95 % point, and how it was found
    tracker_noise_dof: Optional[dict[str, Optional[Number]]] = None
    cov_x_noise_dof: Optional[Number] = None
    cov_x_dof_factor: Optional[Positive] = None
    cov_x_dof_method: Optional[Literal["satterthwaite", "resampled"]] = None
    tracker_scale: Optional[TrackerScale] = None
    view_poses: Optional[ViewPoses] = None  # a cell's cameras' own poses of shared views
    robot_accuracy: Optional[RobotAccuracy] = None  # the arm's stated accuracy, in the verdict covariance
    sigma_rot_deg: Optional[list[Sigma]] = None
    sigma_trans_mm: Optional[list[Sigma]] = None
    sigma_source: Optional[StrictStr] = None
    rms_px_after: Optional[Number] = None
    predicted_error_mm: Optional[Sigma] = None
    robot_model: Optional[Mapping] = None
    validation: Optional[Mapping] = None
    options: Optional[Mapping] = None

    @model_validator(mode="after")
    def _names_match(self):
        names, cov = self.intrinsics_cov_names, self.cov_intrinsics_verdict
        if names is not None and cov is not None and len(cov) != len(names):
            raise damaged(
                f"is {len(cov)}x{len(cov)}",
                f"{len(names)}x{len(names)} (one row per intrinsics_cov_names)",
                field="refinement.cov_intrinsics_verdict",
            )
        return self


class ViewRecord(Open):
    """One entry of ``views``: the view's id and whether the solution used it."""

    id: ViewId
    used: StrictBool = False
    image: Optional[StrictStr] = None
    reason: Optional[StrictStr] = None


class ViewCounts(Open):
    total: Count
    used: Count

    @model_validator(mode="after")
    def _used_of_total(self):
        if self.used > self.total:
            raise damaged(f"is {self.used} of {self.total} views", f"at most total ({self.total})", "n_views.used")
        return self


class Result(Open):
    """result.json: one calibration (``status`` ok: X was computed; ``verdict``: whether to use it).

    The transforms are keyed by their names (``T_end_cam`` / ``T_base_cam`` and ``T_base_board`` /
    ``T_end_board``, from ``mode``); a result with ``status: ok`` must hold its X as a finite rigid
    transform and ``hand_eye``.
    """

    handeye_result: StrictInt = Field(ge=1, description="result.json format version")
    kind: Optional[Literal["camera", "cell"]] = Field(
        default=None, description="camera (one camera, the default) | cell (several cameras of one arm: cameras)"
    )
    status: Literal["ok", "failed"]
    mode: StrictStr = Field(description="eye_in_hand | eye_to_hand (a failed run: also unknown; a cell: cell)")
    mode_source: Optional[StrictStr] = None
    method: Optional[StrictStr] = None
    refined: Optional[StrictBool] = None
    failure_reason: Optional[StrictStr] = None
    verdict: Optional[VerdictName] = None
    verdict_headline: Optional[StrictStr] = None
    run_id: Optional[StrictStr] = None
    T_end_cam: Optional[Rigid] = None
    T_base_cam: Optional[Rigid] = None
    T_base_board: Optional[Rigid] = None
    T_end_board: Optional[Rigid] = None
    hand_eye: Optional[PoseForms] = None
    board: Optional[PoseForms] = None
    intrinsics: Optional[IntrinsicsBlock] = None
    refinement: Optional[Refinement] = None
    views: list[ViewRecord] = Field(default_factory=list)
    n_views: Optional[ViewCounts] = None
    findings: Optional[list[Mapping]] = None
    error: Optional[Mapping] = None
    diagnostics: Optional[Mapping] = None
    provenance: Optional[Mapping] = None
    seconds: Optional[Mapping] = None
    session: Optional[Mapping] = None
    motion: Optional[Mapping] = None
    target: Optional[Mapping] = None
    closed_form: Optional[Mapping] = None
    closed_form_views: Optional[list[StrictStr]] = Field(
        default=None, description="the views the closed forms solved, when not every view with a board pose"
    )
    closed_forms: Optional[Mapping] = None
    qa: Optional[Mapping] = None
    seed: Optional[Mapping] = None
    frames: Optional[Mapping] = None
    mode_evidence: Optional[Mapping] = None
    cameras: Optional[dict[CameraName, "CellCamera"]] = Field(
        default=None, description="a cell: camera name (its session folder's name) -> that camera's result"
    )
    camera_pairs: Optional[dict[StrictStr, "CameraPair"]] = Field(
        default=None, description="a cell: 'a/b' -> T_a_b, the pose of camera b in camera a's frame"
    )
    joint_covariance: Optional["JointBlocks"] = None
    _raw: Optional[dict] = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _meaning(self, info: ValidationInfo):
        if self.kind == "cell":
            _check_cell(self)
            return self
        if self.status != "ok":
            return self
        if self.mode not in MODES:
            raise damaged(f"is {self.mode!r} in a result with status ok", " | ".join(MODES), field="mode")
        if (info.context or {}).get("partial"):  # a program's dict of some parts: what it holds is checked
            return self
        mount = mounting(self.mode)
        if getattr(self, mount.x_name) is None:
            raise damaged("is missing", "a finite 4x4 rigid transform (the result's status is ok)", mount.x_name)
        if self.hand_eye is None:
            raise damaged("is missing", "a mapping (the result's status is ok)", field="hand_eye")
        if self.hand_eye.name not in (None, mount.x_name):
            raise damaged(f"is {self.hand_eye.name!r}", f"{mount.x_name} ({self.mode})", field="hand_eye.name")
        if self.board is not None and self.board.name not in (None, mount.board_name):
            raise damaged(f"is {self.board.name!r}", f"{mount.board_name} ({self.mode})", field="board.name")
        _same_pose(self.hand_eye, getattr(self, mount.x_name), "hand_eye", mount.x_name)
        if self.board is not None and getattr(self, mount.board_name) is not None:
            _same_pose(self.board, getattr(self, mount.board_name), "board", mount.board_name)
        return self

    # -------------------------------------------------------------------- typed accessors
    @property
    def raw(self) -> dict:
        """The dict this result was validated from (as read, after migration), for the fields not typed here."""
        return self._raw if self._raw is not None else self.model_dump(exclude_unset=True)

    @property
    def ok(self) -> bool:
        """X was computed (``status: ok``): the hand-eye matrix is in the file."""
        return self.status == "ok"

    @property
    def x_name(self) -> str:
        """The name of X: ``T_end_cam`` (eye-in-hand) or ``T_base_cam`` (eye-to-hand)."""
        if self.hand_eye is not None and self.hand_eye.name:
            return self.hand_eye.name
        return "T_end_cam" if self.mode == "eye_in_hand" else "T_base_cam"

    @property
    def board_name(self) -> Optional[str]:
        """The name of the board's transform (None when the result does not name it)."""
        if self.board is not None and self.board.name:
            return self.board.name
        return mounting(self.mode).board_name if self.mode in MODES else None

    @property
    def T_x(self) -> Optional[np.ndarray]:
        """(4,4) the hand-eye transform X, None in a result without it."""
        v = getattr(self, self.x_name, None)
        return None if v is None else np.asarray(v, float)

    @property
    def T_board(self) -> Optional[np.ndarray]:
        """(4,4) the board's transform, None in a result without it."""
        v = getattr(self, self.board_name, None) if self.board_name else None
        return None if v is None else np.asarray(v, float)

    @property
    def cov_x(self) -> tuple[Optional[np.ndarray], str]:
        """((6,6) or None, its key): X's covariance the verdict uses, symmetrised.

        ``cov_x_6x6_verdict``, else the model's ``cov_x_6x6``; (None, "none") without one.
        """
        ref = self.refinement
        for key in ("cov_x_6x6_verdict", "cov_x_6x6"):
            v = getattr(ref, key, None) if ref is not None else None
            if v is not None:
                c = np.asarray(v, float)
                return 0.5 * (c + c.T), key
        return None, "none"

    @property
    def intrinsics_sigma(self) -> dict:
        """Name -> sigma of the free intrinsics (the verdict's, else the model's; NaN and null left out)."""
        ref = self.refinement
        sig = (ref.intrinsics_sigma_verdict or ref.intrinsics_sigma or {}) if ref is not None else {}
        return {str(k): float(v) for k, v in sig.items() if v is not None and np.isfinite(v)}

    @property
    def camera(self):
        """The :class:`handeye.camera.Intrinsics` of the result, None without them."""
        return None if self.intrinsics is None else self.intrinsics.to_intrinsics()

    @property
    def is_cell(self) -> bool:
        """The result is a cell of several cameras (``kind: cell``): its X are in ``cameras``."""
        return self.kind == "cell"

    @property
    def camera_names(self) -> list[str]:
        """A cell's camera names, in the file's order; [] for a one-camera result."""
        return list(self.cameras or {})

    def camera_result(self, name: str) -> "Result":
        """One camera of a cell as a one-camera :class:`Result` (its entry as written, with the file's version).

        A name the cell lacks is a KeyError, for the caller (:func:`handeye.contract.single_camera`) to word.
        """
        entry = (self.raw.get("cameras") or {})[name]
        raw = {**entry, "handeye_result": self.handeye_result}
        out = Result.model_validate(raw)
        out._raw = raw
        return out


# ----------------------------------------------------------------------------------------------- cells
#: a camera's name in a cell: its session folder's name, usable in a frame name (``T_cam1_cam2``)
CameraName = Annotated[StrictStr, StringConstraints(pattern=r"^[A-Za-z0-9][A-Za-z0-9_.-]*$", max_length=64)]


class CellCamera(Result):
    """One camera of a cell: a one-camera result (its mode, X, intrinsics, covariances, views, verdict).

    X and its covariances are the joint graph's; the version key is the cell file's.
    """

    handeye_result: Optional[StrictInt] = Field(default=None, ge=1, description="(the cell file's version)")  # type: ignore[assignment]
    kind: Optional[Literal["camera"]] = None


class CameraPair(Open):
    """``camera_pairs['a/b']``: ``T_a_b`` (camera b's pose in camera a's frame) and its covariance."""

    name: StrictStr = Field(description="T_<a>_<b>")
    matrix: Rigid
    cov_6x6: Cov6 = Field(description="tangent (omega, v) of T_a_b, rad and m, as cov_x_6x6")
    cov_6x6_verdict: Optional[Cov6] = None


class JointBlocks(Open):
    """``joint_covariance``: the joint covariance of every estimated block of the cell, one matrix.

    ``blocks`` name the rows in order (e.g. ``cameras.cam1.T_end_cam`` 6, ``cameras.cam1.intrinsics`` k,
    ``T_end_board`` 6, ``dh_offsets`` m), ``sizes`` their row counts.
    """

    blocks: list[StrictStr]
    sizes: list[Count]
    matrix: Covariance

    @model_validator(mode="after")
    def _sizes(self):
        if len(self.blocks) != len(self.sizes):
            raise damaged(f"has {len(self.sizes)} sizes", f"one per block ({len(self.blocks)})", "sizes")
        n = sum(self.sizes)
        if len(self.matrix) != n:
            raise damaged(f"is {len(self.matrix)}x{len(self.matrix)}", f"{n}x{n} (the blocks' sizes)", "matrix")
        return self


def _check_cell(res: "Result") -> None:
    """A cell's meaning: mode ``cell``, its cameras when ok, pairs naming cameras of the cell."""
    if res.mode != "cell":
        raise damaged(f"is {res.mode!r} in a cell", "cell (each camera has its own mode)", field="mode")
    if res.status != "ok":
        return
    if not res.cameras:
        raise damaged("is missing or empty", "one entry per camera (the cell's status is ok)", field="cameras")
    for key, pair in (res.camera_pairs or {}).items():
        a, _, b = key.partition("/")
        if a not in res.cameras or b not in res.cameras or a == b:
            raise damaged(
                f"names {key!r}", f"'a/b' with two cameras of the cell ({', '.join(res.cameras)})", "camera_pairs"
            )
        if pair.name != f"T_{a}_{b}":
            raise damaged(f"is {pair.name!r}", f"T_{a}_{b}", f"camera_pairs.{key}.name")


Result.model_rebuild()
