"""What a result.json says about the hand-eye transform X, the intrinsics and their covariances.

The covariances are those the result's verdict uses (``cov_x_6x6_verdict``, ``intrinsics_sigma_verdict``,
else the model's), in handeye's one tangent. The model's joint covariance of X and the free intrinsics
is read too and carried to the verdict covariances (:func:`verdict_maps`), so a test never mixes the
verdict's X with the model's intrinsics; a kinematic install's DH offsets are read with it.

See docs/recalibrate.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

from ..camera import INTRINSIC_NAMES, Intrinsics
from ..errors import InputError, clip
from ..stats import satterthwaite_dof

ResultLike = Union[str, Path, dict]


@dataclass(frozen=True)
class LoadedResult:
    """The parts of a result.json that recalibration needs (``source``: the path, or "<dict>")."""

    source: str
    status: str
    mode: str
    x_name: str
    board_name: Optional[str]
    T_x: Optional[np.ndarray]  # (4,4)
    T_board: Optional[np.ndarray]  # (4,4)
    cov_x: Optional[np.ndarray]  # (6,6) right tangent of T_x, rotation first
    cov_source: str  # "cov_x_6x6_verdict" (less robot_accuracy's, load_result) | "cov_x_6x6" | "none"
    intrinsics: Optional[Intrinsics]
    intrinsics_sigma: dict  # name -> sigma (only free intrinsics; fixed ones absent)
    intrinsics_source: Optional[str]  # "estimated" | "given" | ... as result.json says
    target: Optional[dict]
    image_size: Optional[tuple]
    sigma_px: Optional[float]
    robot_sigma_mm: Optional[float]
    robot_sigma_deg: Optional[float]
    raw: dict = field(repr=False, default_factory=dict)
    # the joint covariance of X's tangent and the free intrinsics (refinement.cov_x_intrinsics, carried to the
    # verdict covariances by verdict_maps): (names, cross (6,k), intrinsics (k,k)); None in results without it
    cov_x_intrinsics: Optional[tuple] = field(repr=False, default=None)
    # the kinematic robot model's DH offsets and their covariance with X and the intrinsics (the same source):
    # (offsets (m,), cross with X (6,m), cross with the intrinsics (k,m), (m,m)); None without that model
    dh_joint: Optional[tuple] = field(repr=False, default=None)
    # what compare conditions X on the intrinsics with: (names, the model's cross-covariance C (6,k) and
    # intrinsics covariance K (k,k) as result.json stores them, A C (6,k) with A the verdict map of X). C K^-1 is
    # the model's geometry (how an intrinsics error moves X); with A C, X's part the intrinsics do not explain
    # gets the verdict's inflation of X: A (S - C K^-1 C^T) A^T
    x_on_intrinsics: Optional[tuple] = field(repr=False, default=None)
    # the board pose's model covariance (6,6) and its cross-covariance with the free intrinsics (6,k), the latter
    # carried like the intrinsics (to their verdict sigmas); None in results without them
    board_joint: Optional[tuple] = field(repr=False, default=None)
    # the camera of a cell this result is (None: a one-camera result.json)
    camera: Optional[str] = None

    @property
    def label(self) -> str:
        """The result as people name it: its source, with the camera of a cell."""
        return self.source if self.camera is None else f"{self.source} (camera {self.camera})"

    @property
    def ok(self) -> bool:
        return self.status == "ok" and self.T_x is not None

    def with_board_turned(self, H: np.ndarray) -> "LoadedResult":
        """The result with its board frame moved by ``H`` (4,4) and the board's covariance carried along.

        ``T_board H``, and the board's covariance
        carried along (right tangent: ``Ad(H^-1)``). A symmetric board numbered from another corner in a later
        session has its frame turned so (:func:`handeye.diagnose.consistency.board_turns`); X does not change.
        """
        from dataclasses import replace

        from ..frames import inv_T, se3_adjoint

        if self.T_board is None:
            return self
        A = se3_adjoint(inv_T(np.asarray(H, float)))
        bj = self.board_joint
        if bj is not None:
            bj = (A @ bj[0] @ A.T,) + tuple(None if c is None else A @ c for c in bj[1:])
        return replace(self, T_board=self.T_board @ H, board_joint=bj)

    @property
    def cov_x_given_intrinsics(self) -> Optional[np.ndarray]:
        """(6,6) the covariance of X were its intrinsics known.

        ``cov_x - C K^-1 C^T`` with the joint covariance (the installed uncertainty a verification that
        shares these intrinsics faces); ``cov_x`` without it.
        """
        if self.cov_x is None or self.cov_x_intrinsics is None:
            return self.cov_x
        _, C, K = self.cov_x_intrinsics
        S = self.cov_x - C @ np.linalg.solve(K, C.T)
        return 0.5 * (S + S.T)

    @property
    def robot_noise_dof(self) -> Optional[float]:
        """Degrees of freedom of the robot noise level the calibration estimated.

        Degrees of freedom of the robot noise level the calibration estimated (``refinement.robot_noise_dof``:
        one per estimated robot sigma, and the DH prior's scale where the views widened it): Satterthwaite's for
        their sum with equal shares (the shares each has in X's covariance are not recorded: when one dominates,
        the equal shares overstate the degrees of freedom; the pixel noise's part, known far better, is left out,
        which understates them). None when it estimated none (the noise stated, a pose-only result, a refinement
        without the outlier loop, whose sigmas are robust estimates, or an older result).
        On simulated 20-view installs: about 50 eye-in-hand (rotation 50, translation 16) and 75 eye-to-hand; a
        widened DH prior (10-17 degrees of freedom) brings a kinematic install's to about 40-60.
        """
        d = (self.raw.get("refinement") or {}).get("robot_noise_dof")
        vals = [_float(v) for v in d.values()] if isinstance(d, dict) else []
        vals = [v for v in vals if v is not None and v > 0]
        return satterthwaite_dof([1.0 / len(vals)] * len(vals), vals) if vals else None

    @property
    def cov_x_carries_noise_dof(self) -> bool:
        """Whether X's covariance was multiplied for the estimated noise levels' degrees of freedom already.

        ``refinement.cov_x_dof_factor`` recorded (:func:`handeye.refine.result.x_dof_factor`, a pose-only result's
        tracker sigmas): its chi-square ellipsoid is the 95 % region as it stands.
        """
        return (self.raw.get("refinement") or {}).get("cov_x_dof_factor") is not None

    @property
    def joints_recorded(self) -> bool:
        """The install's kinematic robot model took the views' recorded joint angles (not inverse kinematics)."""
        return ((self.raw.get("refinement") or {}).get("robot_model") or {}).get("joint_angles") == "recorded"

    @property
    def cov_x_given_shared(self) -> Optional[np.ndarray]:
        """(6,6) the covariance of X given the intrinsics and the arm's DH offsets of a kinematic install.

        (6,6) the covariance of X given the intrinsics and the arm's DH offsets of a kinematic install (what a
        verification faces when it shares both: :func:`handeye.recal.verify.shares_dh`);
        :attr:`cov_x_given_intrinsics` for an install without DH offsets.
        """
        if self.cov_x_intrinsics is None or self.dh_joint is None:
            return self.cov_x_given_intrinsics
        _, C, K = self.cov_x_intrinsics
        _, Cd, Kd, D = self.dh_joint
        Cs, Ks = np.hstack([C, Cd]), np.block([[K, Kd], [Kd.T, D]])
        S = self.cov_x - Cs @ np.linalg.solve(Ks, Cs.T)
        return 0.5 * (S + S.T)


def axes_words(frame: str) -> str:
    """Which axes a change of ``frame`` is given along, in words.

    Which axes a change of ``frame`` (T_parent_cam) is given along, for people: the translation the
    parent's, the rotation the camera's (:func:`handeye.recal.verify.change_in_result_frame`).
    """
    parent = {"T_end_cam": "flange", "T_base_cam": "robot base"}.get(frame, "parent frame")
    return f"mm along the {parent} axes, deg about the camera axes"


def require_matrix(r: LoadedResult) -> None:
    """Refuse an installed result without a hand-eye matrix (its calibration failed): verify and collect need one."""
    if not r.ok:
        raise InputError(
            "the installed calibration failed: its result has no hand-eye matrix",
            path=r.source,
            hint="verify against a calibration that computed one",
        )


def unfit_note(r: LoadedResult) -> Optional[str]:
    """A warning for a result whose transform exists but whose verdict says it is not fit for use.

    A warning for a result whose transform exists but whose verdict says it is not fit for use (FAIL), or
    None: commands that use it anyway (verify, compare, apply) say so instead of trusting it silently.
    """
    verdict = str(r.raw.get("verdict") or "").upper()
    if not r.ok or verdict != "FAIL":
        return None
    head = str(r.raw.get("verdict_headline") or "").rstrip(".")
    return f"{r.source}: this calibration's verdict is FAIL" + (f" ({head})" if head else "") + "; it is used as it is"


def _matrix(v, shape) -> Optional[np.ndarray]:
    if v is None:
        return None
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        return None
    return a if a.shape == shape and np.all(np.isfinite(a)) else None


def load_result(result: ResultLike, *, camera: Optional[str] = None, absolute: bool = False) -> LoadedResult:
    """Read a result folder, a result.json path or an already loaded dict, through the one reader.

    ``cov_x`` is the verdict's covariance of X, less the arm's stated accuracy (``refinement.robot_accuracy``)
    unless ``absolute``: that error is common to every session of the same arm, so it cancels where a result
    meets another of its arm (verify, compare, a prior); export and the fleet index state it (``absolute``).

    :func:`handeye.contract.read_result` checks every field read here: a missing, foreign or damaged file
    raises :class:`~handeye.errors.InputError` naming the field; a failed result loads with
    ``status != "ok"``. A cell is read as its camera ``camera`` (:func:`handeye.contract.single_camera`:
    without it, or with a name the cell lacks, one InputError naming its cameras and ``--camera``).
    """
    from ..contract import read_result, single_camera, validate_result
    from ..output import plain

    if isinstance(result, dict):
        m, source = validate_result(plain(result), require_version=False), "<dict>"
    else:
        p = Path(result)
        m, source = read_result(p), str(p / "result.json" if p.is_dir() else p)
    name = camera if m.is_cell else None
    if m.is_cell and camera is None and len(m.camera_names) == 1:
        name = m.camera_names[0]
    m = single_camera(m, camera, source=source)
    d = m.raw
    ref = d.get("refinement") or {}
    cov, cov_source = m.cov_x
    acc = ref.get("robot_accuracy")
    if cov is not None and not absolute and isinstance(acc, dict) and cov_source == "cov_x_6x6_verdict":
        cov = cov - np.asarray(acc["cov_x_6x6"], float)
        cov_source = "cov_x_6x6_verdict less robot_accuracy.cov_x_6x6"
    if cov is not None:
        _check_parametrisation(ref.get("cov_parametrisation"), source)
    intr = m.intrinsics
    return LoadedResult(
        source=source,
        status=m.status,
        mode=m.mode,
        x_name=m.x_name,
        board_name=m.board_name,
        T_x=m.T_x,
        T_board=m.T_board,
        cov_x=cov,
        cov_source=cov_source,
        intrinsics=m.camera,
        intrinsics_sigma=m.intrinsics_sigma,
        intrinsics_source=None if intr is None else intr.source,
        target=d.get("target"),
        image_size=tuple(intr.image_size) if intr is not None and intr.image_size else None,
        sigma_px=_float(ref.get("sigma_px")),
        robot_sigma_mm=_float(ref.get("robot_sigma_mm")),
        robot_sigma_deg=_float(ref.get("robot_sigma_deg")),
        raw=d,
        camera=name,
        **_joints(ref, cov),
    )


def session_camera(
    result: ResultLike,
    session_path,
    camera: Optional[str] = None,
    *,
    what: str = "the installed result",
    hint: str = "choose the camera with --camera NAME (or name the session folder after its camera)",
) -> Optional[str]:
    """The camera of a cell a session of one camera is checked against.

    ``camera`` when given, else the session folder's name when the cell has a camera of that name (a cell of
    one camera: that one); None for a one-camera result. A cell none of whose cameras the folder names is
    one InputError naming the cameras (``what`` names the result, ``hint`` what to do).
    """
    from ..contract import read_result

    if camera is not None or isinstance(result, dict) or session_path is None:
        return camera
    names = read_result(Path(result)).camera_names
    if not names:
        return None
    name = Path(session_path).resolve().name
    if name in names or len(names) == 1:
        return name if name in names else names[0]
    raise InputError(
        f"{what} is a cell of {len(names)} cameras ({', '.join(names)}) and the session folder {name!r} names "
        "none of them",
        path=str(result),
        hint=hint,
    )


def _joints(ref: dict, cov_x: Optional[np.ndarray]) -> dict:
    """``cov_x_intrinsics`` and ``dh_joint`` of a LoadedResult from result.json's refinement block.

    ``cov_x_intrinsics`` and ``dh_joint`` of a LoadedResult from result.json's refinement block, carried to
    the verdict covariances (:func:`verdict_maps`).
    """
    j = ref.get("cov_x_intrinsics")
    joint = _joint(j)
    dh = _dh_joint(j, len(joint[0])) if joint is not None and j is not None else None  # _joint(j): j a dict
    maps = verdict_maps(
        joint,
        cov_x_model=_matrix(ref.get("cov_x_6x6"), (6, 6)),
        cov_x=cov_x,
        intrinsics_verdict=_intrinsics_verdict(ref),
        intrinsics_full=(ref.get("validation") or {}).get("intrinsics_model") == "full",
    )
    board = None
    if joint is not None and j is not None:
        cb, cbk = _matrix(ref.get("cov_board_6x6"), (6, 6)), _matrix(j.get("cross_board_6xk"), (6, len(joint[0])))
        board = None if cb is None or cbk is None else (0.5 * (cb + cb.T), cbk)
    if maps is None:
        return {
            "cov_x_intrinsics": joint,
            "dh_joint": dh,
            "board_joint": board,
            "x_on_intrinsics": None if joint is None else joint + (joint[1],),
        }
    A, B = maps
    assert joint is not None, "verdict_maps needs the joint covariance"
    names, C, K = joint
    K2 = B @ K @ B.T
    if dh is not None:
        dh = (dh[0], A @ dh[1], B @ dh[2], dh[3])
    if board is not None:
        board = (board[0], board[1] @ B.T)
    return {
        "cov_x_intrinsics": (names, A @ C @ B.T, 0.5 * (K2 + K2.T)),
        "dh_joint": dh,
        "board_joint": board,
        "x_on_intrinsics": (names, C, K, A @ C),
    }


def _dh_joint(j: dict, k: int) -> Optional[tuple]:
    """The DH offsets and their cross-covariances from cov_x_intrinsics' DH keys, or None.

    (offsets (m,), cross with X (6,m), cross with the intrinsics (k,m), (m,m)) from cov_x_intrinsics' DH
    keys; None when absent or malformed.
    """
    dh = j.get("dh_offsets")
    if dh is None or np.size(dh) == 0:
        return None
    m = int(np.size(dh))
    parts = (
        _matrix(dh, (m,)),
        _matrix(j.get("cross_6xm"), (6, m)),
        _matrix(j.get("cross_kxm"), (k, m)),
        _matrix(j.get("dh_mxm"), (m, m)),
    )
    return None if any(p is None for p in parts) else parts


def stretch(cov_model: np.ndarray, cov_target: np.ndarray) -> np.ndarray:
    """The map ``A`` with ``A cov_model A^T = cov_target`` that moves least.

    With ``cov_model = L L^T`` and ``L^-1 cov_target L^-T = U D U^T``, ``A = L U D^(1/2) U^T L^-1`` (the
    identity where the two agree; the verdict covariance of :mod:`handeye.refine.validation` differs from the
    model's only along the generalised eigenvectors whose eigenvalue exceeds 1).
    """
    L = np.linalg.cholesky(0.5 * (cov_model + cov_model.T))
    W = np.linalg.solve(L, np.linalg.solve(L, 0.5 * (cov_target + cov_target.T)).T)
    d, U = np.linalg.eigh(0.5 * (W + W.T))
    return L @ (U * np.sqrt(np.maximum(d, 0.0))) @ U.T @ np.linalg.inv(L)


def verdict_maps(
    joint: Optional[tuple],
    *,
    cov_x_model: Optional[np.ndarray],
    cov_x: Optional[np.ndarray],
    intrinsics_verdict: Optional[tuple],
    intrinsics_full: bool = False,
) -> Optional[tuple]:
    """(A, B) that carry the model's joint covariance of X and the intrinsics to the verdict ones.

    (A, B) that carry the model's joint covariance ``(names, cross (6,k), K (k,k))`` of X and the free
    intrinsics to the verdict covariances: ``J S J^T`` with ``J = diag(A, B, I)`` (I: the DH offsets of the
    kinematic robot model, which have no verdict covariance), ``A`` = :func:`stretch` of the model's X
    covariance ``cov_x_model`` to the verdict's ``cov_x``. ``B`` carries K to the intrinsics' verdict
    covariance (``intrinsics_verdict``: (names, (n,n)) covering ``names``):

    * ``intrinsics_full`` (the validation measured the intrinsics against their joint model covariance, K):
      :func:`stretch` of K to the verdict, which then keeps the correlations the data determine;
    * otherwise (a result validated against the model sigmas one by one, whose verdict's off-diagonal terms are
      not the data's: fx and fy, nearly fully correlated, would get a difference fx - fy as uncertain as each
      of them): the diagonal map that gives each intrinsic its verdict sigma and keeps the model's correlations.

    Positive definite whenever the model's joint is (and every verdict sigma positive), with the model's
    canonical correlations between the blocks. A block without its verdict covariance keeps the model's
    (identity); None: no joint, or a covariance that is not positive definite (the model's joint is used as
    stored).
    """
    if joint is None:
        return None
    names, C, K = joint
    try:
        A = np.eye(6) if cov_x_model is None or cov_x is None else stretch(cov_x_model, cov_x)
        B = np.eye(len(names))
        if intrinsics_verdict is not None:
            vn, V = intrinsics_verdict
            if set(names) <= set(vn):
                idx = [vn.index(n) for n in names]
                if intrinsics_full:
                    B = stretch(K, V[np.ix_(idx, idx)])
                else:
                    var_v, var_m = np.diag(V)[idx], np.diag(K)
                    if not (np.all(var_v > 0) and np.all(var_m > 0)):  # a singular map: the joint as stored
                        raise np.linalg.LinAlgError("an intrinsics sigma is not positive")
                    B = np.diag(np.sqrt(var_v) / np.sqrt(var_m))
    except np.linalg.LinAlgError:
        return None
    return A, B


def _intrinsics_verdict(ref: dict) -> Optional[tuple]:
    """(names, covariance) of refinement.cov_intrinsics_verdict with its intrinsics_cov_names; None if absent."""
    names = ref.get("intrinsics_cov_names")
    if not isinstance(names, list) or not names:
        return None
    V = _matrix(ref.get("cov_intrinsics_verdict"), (len(names), len(names)))
    return None if V is None else ([str(n) for n in names], V)


def _joint(j) -> Optional[tuple]:
    """(names, cross (6,k), intrinsics (k,k)) from refinement.cov_x_intrinsics, None when absent or malformed."""
    if not isinstance(j, dict) or not isinstance(j.get("intrinsics"), list):
        return None
    names = tuple(str(n) for n in j["intrinsics"])
    k = len(names)
    cross, kk = _matrix(j.get("cross_6xk"), (6, k)), _matrix(j.get("intrinsics_kxk"), (k, k))
    if k == 0 or cross is None or kk is None or not set(names) <= set(INTRINSIC_NAMES):
        return None
    return names, cross, 0.5 * (kk + kk.T)


def _float(v) -> Optional[float]:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if np.isfinite(f) else None


def _check_parametrisation(text, source: str) -> None:
    """The covariance must be in handeye's one tangent (right perturbation, rotation first)."""
    t = str(text or "")
    if t and not ("right perturbation" in t and "rotation first" in t):
        raise InputError(
            "the covariance of X is in an unknown parametrisation",
            path=source,
            expected="right perturbation, rotation first (GTSAM Pose3 tangent)",
            received=clip(t, 80),
            hint="recompute the result with this version of handeye calibrate",
        )


#: the prior hook's term on X when the new views alone should decide it: 1 rad, 1 m (vague)
VAGUE_COV_X = np.eye(6)


def installed_prior(
    installed: LoadedResult, *, session_intrinsics: bool, cov_x: Optional[np.ndarray] = None, board: bool = False
):
    """(Prior or None, names of intrinsics to hold) from the installed result.

    (Prior or None, names of intrinsics to hold) from the installed result: X with ``cov_x``
    (default: the installed covariance) and, unless the session brings its own intrinsics, the
    installed intrinsics with their sigmas (those without a sigma are held at the installed value) and, where the
    result has the joint covariance, the correlations among them (fx and fy move together) and, when X's prior
    is the installed covariance, their correlation with X (one joint prior). ``board``: the installed board pose
    with its covariance too (the board has not moved), jointly with the intrinsics when X's prior is not.
    """
    from ..refine.options import Prior

    if board and cov_x is None:  # result.json has no cross-covariance of X and the board: not both as priors
        raise ValueError("the installed board pose is a prior only with X's prior replaced (cov_x)")
    if installed.cov_x is None or installed.T_x is None:
        raise InputError(
            "the installed result has no covariance of X",
            path=installed.source,
            hint="use a result calibrated with the refinement (without --no-refine)",
        )
    cov = installed.cov_x if cov_x is None else cov_x
    with_board = board and installed.board_joint is not None and installed.T_board is not None
    board_kw: dict[str, Any] = (
        dict(T_board=installed.T_board, cov_board=installed.board_joint[0])
        if with_board and installed.board_joint is not None
        else {}
    )
    if session_intrinsics or installed.intrinsics is None:
        return Prior(T_x=installed.T_x, cov_x=cov, **board_kw), ()
    sig = np.array([installed.intrinsics_sigma.get(n, 0.0) for n in INTRINSIC_NAMES])
    fixed = tuple(n for n, s in zip(INTRINSIC_NAMES, sig, strict=False) if not s > 0)
    cov_k = np.diag(np.where(sig > 0, sig, 1.0) ** 2)
    cross = None
    if installed.cov_x_intrinsics is not None:
        names, C, K = installed.cov_x_intrinsics
        idx = [INTRINSIC_NAMES.index(n) for n in names]
        if all(sig[i] > 0 for i in idx) and np.allclose(np.sqrt(np.diag(K)), sig[idx], rtol=1e-6):
            cov_k[np.ix_(idx, idx)] = K  # the same sigmas, with their correlations
            if cov_x is None:
                cross = np.zeros((6, len(INTRINSIC_NAMES)))
                cross[:, idx] = C
            elif with_board:  # X's prior replaced (board requires it): the board joins the intrinsics instead
                board_kw["cov_board_intrinsics"] = np.zeros((6, len(INTRINSIC_NAMES)))
                board_kw["cov_board_intrinsics"][:, idx] = installed.board_joint[1]  # type: ignore[index]  # with_board
    return Prior(
        T_x=installed.T_x,
        cov_x=cov,
        intrinsics=installed.intrinsics,
        cov_intrinsics=cov_k,
        cov_x_intrinsics=cross,
        **board_kw,
    ), fixed


def result_from_refinement(refined, *, target, validation=None) -> dict:
    """The parts of result.json that :func:`load_result` reads.

    The parts of result.json that :func:`load_result` reads, from a
    :class:`~handeye.refine.RefineResult` and the target spec: for programs (and the benchmarks)
    that refine without writing a result folder. ``validation``
    (:func:`handeye.refine.validation.validate` of ``refined``) adds the verdict covariances as
    result.json has them (:func:`handeye.results.validation_fields`).
    """
    from ..output import plain

    ok = refined.status == "ok"
    ref = refined.to_dict()
    if validation is not None:
        from ..results import validation_fields

        ref.update(validation_fields(refined, validation))
    d = {
        "handeye_result": 1,
        "status": refined.status,
        "mode": refined.mode,
        "hand_eye": {"name": refined.x_name},
        "board": {"name": refined.board_name},
        "intrinsics": dict(refined.intrinsics.to_dict(), source="refined"),
        "refinement": ref,
        "target": target.to_dict(),
    }
    if ok:
        d[refined.x_name] = refined.T_x
        d[refined.board_name] = refined.T_board
    return plain(d)
