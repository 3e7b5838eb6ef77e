"""Robot error models of the simulator: how the pose an arm reports differs from where its flange is.

:data:`ROBOT_ERROR_MODELS`: ``none`` (exact), ``iid`` (a small independent error per view in the end
frame) and ``kinematic`` (a true arm whose DH table is off the nominal one by 0.1-0.5 mm and
0.01-0.05 deg, read by encoders with noise and reported through the nominal table, so the error is
pose-dependent and correlated across views, as on real arms).

See docs/robot_error.md for the model and its default sizes.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import ConfigError
from ..kinematics import DHChain, default_ik_seeds, load_arm, solve_ik

ROBOT_ERROR_MODELS = ("none", "iid", "kinematic")
DEFAULT_ARM = "rm65"
DH_LENGTH_ERROR_MM = (0.1, 0.5)
DH_ANGLE_ERROR_DEG = (0.01, 0.05)
ENCODER_SIGMA_DEG = 0.005


def check_model_name(name: str) -> str:
    if name not in ROBOT_ERROR_MODELS:
        raise ConfigError("unknown robot error model", expected=" | ".join(ROBOT_ERROR_MODELS), received=repr(name))
    return name


@dataclass(frozen=True)
class KinematicRobotError:
    """The kinematic robot error of one session: nominal arm, true arm and encoder noise.

    The kinematic robot error of one session: the nominal (published) arm the controller computes
    with, the true arm, and the per-joint encoder noise sigma (radians).
    """

    nominal: DHChain
    true: DHChain
    encoder_sigma_rad: float
    arm: str = DEFAULT_ARM

    @property
    def dh_error(self) -> np.ndarray:  # shape (n, 4): true minus nominal (m, rad)
        return self.true.dh - self.nominal.dh

    def describe(self) -> dict:
        """JSON-ready description (ground_truth.json)."""
        err = self.dh_error
        return {
            "model": "kinematic",
            "arm": self.arm,
            "arm_name": self.nominal.name,
            "dh_convention": self.nominal.convention,
            "dh_columns": ["a_m", "alpha_rad", "d_m", "theta_offset_rad"],
            "dh_nominal": self.nominal.dh.tolist(),
            "dh_true": self.true.dh.tolist(),
            "dh_error_mm_deg": np.column_stack(
                [err[:, 0] * 1e3, np.degrees(err[:, 1]), err[:, 2] * 1e3, np.degrees(err[:, 3])]
            ).tolist(),
            "encoder_sigma_deg": float(np.degrees(self.encoder_sigma_rad)),
            "convention": (
                "T_base_end_reported = FK_nominal(joints_encoder), joints_encoder = joints_true + "
                "N(0, encoder_sigma) per joint and view; the flange is at FK_true(joints_true)"
            ),
        }


def sample_true_arm(
    nominal: DHChain,
    *,
    rng: np.random.Generator,
    length_error_mm: tuple[float, float] = DH_LENGTH_ERROR_MM,
    angle_error_deg: tuple[float, float] = DH_ANGLE_ERROR_DEG,
) -> DHChain:
    """``nominal`` with every DH parameter off by a random amount within the given bounds.

    ``nominal`` with every a and d off by a magnitude uniform in ``length_error_mm`` and every alpha
    and theta_offset by one uniform in ``angle_error_deg``, each with a random sign.
    """
    lo_l, hi_l = (float(x) for x in length_error_mm)
    lo_a, hi_a = (float(x) for x in angle_error_deg)
    if not (0 <= lo_l <= hi_l and 0 <= lo_a <= hi_a):
        raise ConfigError(
            "invalid DH error range",
            expected="0 <= low <= high",
            received=f"length {length_error_mm} mm, angle {angle_error_deg} deg",
        )
    n = nominal.n_joints
    mag = np.empty((n, 4))
    mag[:, [0, 2]] = rng.uniform(lo_l, hi_l, size=(n, 2)) * 1e-3
    mag[:, [1, 3]] = np.radians(rng.uniform(lo_a, hi_a, size=(n, 2)))
    sign = rng.choice([-1.0, 1.0], size=(n, 4))
    return nominal.with_dh(nominal.dh + sign * mag, name=nominal.name + " (perturbed)")


def make_kinematic_error(
    *,
    rng: np.random.Generator,
    arm: str = DEFAULT_ARM,
    length_error_mm: tuple[float, float] = DH_LENGTH_ERROR_MM,
    angle_error_deg: tuple[float, float] = DH_ANGLE_ERROR_DEG,
    encoder_sigma_deg: float = ENCODER_SIGMA_DEG,
) -> KinematicRobotError:
    """One session's kinematic robot error (the true arm drawn from ``rng``)."""
    if encoder_sigma_deg < 0:
        raise ConfigError("negative encoder noise", expected=">= 0 deg", received=str(encoder_sigma_deg))
    nominal = load_arm(arm)
    true = sample_true_arm(nominal, rng=rng, length_error_mm=length_error_mm, angle_error_deg=angle_error_deg)
    return KinematicRobotError(
        nominal=nominal, true=true, encoder_sigma_rad=float(np.radians(encoder_sigma_deg)), arm=str(arm)
    )


@functools.lru_cache(maxsize=None)
def _wrist_reach(arm: str) -> tuple[float, float, float]:
    """(shoulder height, last link's d, largest wrist distance from the shoulder) of a preset.

    (height of the shoulder above the base, last link's d, the largest distance of the wrist point
    from the shoulder) of a preset. The wrist point is the flange minus the last d along the flange z
    (the wrist centre of arms with a spherical wrist). From 4000 configurations within the joint
    limits (a fixed sample, so always the same).
    """
    chain = load_arm(arm)
    rng = np.random.default_rng(12345)
    lim = chain.joint_limits_rad if chain.joint_limits_rad is not None else np.tile([-np.pi, np.pi], (6, 1))
    q = rng.uniform(lim[:, 0], lim[:, 1], size=(4000, chain.n_joints))
    h, d_last = float(chain.dh[0, 2]), float(chain.dh[-1, 2])
    T = chain.T_base_end(q)
    w = T[:, :3, 3] - d_last * T[:, :3, 2] - [0.0, 0.0, h]
    return h, d_last, float(np.max(np.linalg.norm(w, axis=1)))


def workspace_scale(arm: str) -> float:
    """How much smaller than the simulator's default rig the rig must be for ``arm``.

    How much smaller than the simulator's default rig (made for a 1.3 m reach) the rig must be for ``arm``:
    the largest wrist distance from the shoulder over 1 m, at most 1.
    """
    return float(min(1.0, _wrist_reach(arm)[2] / 1.0))


def reachable(
    error: KinematicRobotError, T_base_end: np.ndarray, *, margin: float = 0.98, near: Optional[np.ndarray] = None
) -> Optional[np.ndarray]:
    """True joint angles (n,) that put the true arm's flange at ``T_base_end``, or None (out of reach).

    A wrist point beyond ``margin`` of the arm's largest wrist distance is refused at once; otherwise
    the inverse kinematics decides: from the default seeds (any arm configuration), or with ``near``
    only from there (the solution a controller reaches from the arm's current configuration).
    """
    h, d_last, r = _wrist_reach(error.arm)
    T = np.asarray(T_base_end, float)
    if np.linalg.norm(T[:3, 3] - d_last * T[:3, 2] - [0.0, 0.0, h]) > margin * r:
        return None
    seeds = [np.asarray(near, float)] if near is not None else default_ik_seeds(error.true, T)
    return solve_ik(error.true, T, seeds=seeds, max_iterations=30)


class OneConfiguration:
    """Reachability of poses in ONE arm configuration.

    Reachability of poses in ONE arm configuration (shoulder, elbow and wrist on the sides of the
    first reachable pose), as a capture sequence has it: an operator jogging the arm, or a controller
    moving it to the next Cartesian pose, takes the solution nearest the current joints, and a pose that
    needs the arm to flip over is not one of the session's. Without this, poses reached in another
    configuration carry a different kinematic error (DH offsets act through other joint angles) than
    the rest, which no real capture sequence does. Call it as ``pose_ok``; ``reference`` is set by the
    first reachable pose.
    """

    def __init__(self, error: KinematicRobotError, *, any_configuration: bool = False):
        self.error = error
        self.reference: Optional[np.ndarray] = None
        self.any_configuration = any_configuration  # each pose in whichever configuration reaches it first
        self._drawn: dict[bytes, np.ndarray] = {}  # the joint angles of the poses draw_pose returned

    def joints(self, T_base_end: np.ndarray) -> Optional[np.ndarray]:
        drawn = self._drawn.get(np.asarray(T_base_end, float).tobytes())
        if drawn is not None:  # a pose of draw_pose: its own move (the inverse kinematics may not find it)
            return drawn
        if self.any_configuration:
            return reachable(self.error, T_base_end)
        q = reachable(self.error, T_base_end, near=self.reference)
        if q is None:
            return None
        if self.reference is None:
            self.reference = q
        elif not self.same_configuration(q):
            return None
        return q

    def same_configuration(self, q: np.ndarray, *, steps: int = 16) -> bool:
        """Whether the straight joint-space move from the reference to ``q`` crosses no singularity.

        Whether the straight joint-space move from the reference to ``q`` (both within the limits) crosses
        no singularity: the sign of det J (the joint Jacobian of the flange pose) stays the same along it.
        A shoulder, elbow or wrist flip is a crossing of the singularity between the two configurations.
        """
        assert self.reference is not None, "the first reachable pose sets the reference"
        s = np.linspace(0.0, 1.0, steps)[:, None]
        path = self.reference[None, :] + s * (np.asarray(q, float) - self.reference)[None, :]
        chain = self.error.true
        det = np.linalg.det(chain._jacobian_joints_frames(chain._frames(path)))
        return bool(np.all(det > 0) or np.all(det < 0))

    def __call__(self, T_base_end: np.ndarray) -> bool:
        return self.joints(T_base_end) is not None

    def draw_pose(self, rng: np.random.Generator, *, span_rad: float = np.pi / 2) -> Optional[np.ndarray]:
        """A true flange pose (4,4) the arm reaches by one random move of its joints, or None.

        Each joint moves by up to ``span_rad`` from the reference configuration (the arm's home before
        one is set, or with ``any_configuration``), as an operator jogs the arm; None when the move
        leaves the joint limits or crosses a singularity from the reference (another configuration).
        """
        chain = self.error.true
        own = self.reference is not None and not self.any_configuration
        start = self.reference if own else chain.home_rad
        start = np.zeros(chain.n_joints) if start is None else np.asarray(start, float)
        q = start + rng.uniform(-span_rad, span_rad, chain.n_joints)
        if not chain.within_limits(q) or (own and not self.same_configuration(q)):
            return None
        T = chain.T_base_end(q)
        self._drawn[T.tobytes()] = q
        return T


def joints_for_poses(
    error: KinematicRobotError, T_base_end_true: np.ndarray, *, configuration: Optional[OneConfiguration] = None
) -> np.ndarray:
    """(N, n) true joint angles of the true arm at each (N,4,4) true flange pose.

    (N, n) true joint angles of the true arm at each (N,4,4) true flange pose (in ``configuration``
    when given: the one the poses were sampled in).
    """
    out = []
    for k, T in enumerate(np.asarray(T_base_end_true, float).reshape(-1, 4, 4)):
        q = configuration.joints(T) if configuration is not None else reachable(error, T)
        if q is None:
            raise ConfigError(
                f"pose {k + 1} is out of reach of the {error.nominal.name}",
                expected="poses the arm can reach within its joint limits",
                received=f"flange at {np.round(T[:3, 3], 3).tolist()} m",
                hint="sample the views with the arm's reachability check (pose_ok)",
            )
        out.append(q)
    return np.array(out).reshape(-1, error.nominal.n_joints)


def report_poses(
    error: KinematicRobotError, joints_true: np.ndarray, *, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """(joints_encoder (N, n), T_base_end_reported (N,4,4)).

    The encoder readings and the nominal model's flange poses from them.
    """
    q = np.asarray(joints_true, float).reshape(-1, error.nominal.n_joints)
    q_enc = q + rng.normal(0.0, error.encoder_sigma_rad, size=q.shape)
    return q_enc, error.nominal.T_base_end(q_enc).reshape(-1, 4, 4)


def write_native_session(folder: Path) -> Path:
    """``session.yaml`` with the joint angles in a simulated kinematic session folder.

    ``session.yaml`` in a simulated kinematic folder (:func:`handeye.sim.vendor.write_vendor_session` with
    ``robot_error="kinematic"``): the same images and reported poses, each view's encoder joint angles
    (``joints:``) and ``robot:`` naming the arm, so that the refinement uses the kinematic robot error model
    with the joints the arm recorded. A vendor folder (poses.txt) gets one (a session.yaml is read before
    poses.txt); a target the vendor layout cannot describe already has its session.yaml, which gets the
    joints and the arm. Returns its path.
    """
    import json

    import yaml

    from ..kinematics import PRESETS
    from ..output import atomic_write_text

    folder = Path(folder)
    truth = json.loads((folder / "ground_truth.json").read_text(encoding="utf-8"))
    model = truth.get("robot_error") or {}
    if model.get("model") != "kinematic":
        raise ConfigError(
            "not a kinematic simulated session",
            path=folder / "ground_truth.json",
            expected="robot_error model kinematic",
            received=repr(model.get("model")),
        )
    arm = str(model["arm"])
    joints = {vid: [float(x) for x in v["joints_encoder"]] for vid, v in truth["views"].items()}
    if (folder / "poses.txt").exists():
        lines = [ln for ln in (folder / "poses.txt").read_text(encoding="utf-8").splitlines() if ln.strip()]
        doc = {
            "handeye_session": 1,
            "mode": truth["mode"],
            "target": truth["target"],
            "pose_format": {"rotation": "euler"},
            "views": [
                {"id": vid, "image": v["image"], "pose": [float(x) for x in lines[k].split(",")]}
                for k, (vid, v) in enumerate(truth["views"].items())
            ],
        }
    else:
        doc = yaml.safe_load((folder / "session.yaml").read_text(encoding="utf-8"))
    doc = {
        "handeye_session": 1,
        "mode": doc.get("mode", truth["mode"]),
        "robot": arm if arm in PRESETS else str(Path(arm).resolve()),
        **{k: v for k, v in doc.items() if k not in ("handeye_session", "mode", "robot")},
    }
    doc["views"] = [{**v, "joints": joints[str(v["id"])]} for v in doc["views"]]
    return atomic_write_text(folder / "session.yaml", yaml.safe_dump(doc, sort_keys=False))
