"""Forward kinematics of a serial arm from a Denavit-Hartenberg table, with its Jacobians (pure numpy).

A :class:`DHChain` holds one row ``(a, alpha, d, theta_offset)`` per revolute joint (metres, radians)
in the ``standard`` or ``modified`` convention; ``T_base_end`` is the product of the joint transforms
and the DH angle is the encoder's ``q + theta_offset``. Jacobians in ``q`` and in the DH parameters
use the tangent of :mod:`handeye.frames`. :func:`load_arm` reads a shipped preset
(``configs/robots/``: ``rm65`` and Universal Robots' arms), a file of the same form or the JSON form
other tools write.

See docs/robot_error.md.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Optional, Sequence, Union

import numpy as np

from .config import arm_presets
from .errors import ConfigError, clip
from .frames import inv_T, rotvec_from_R, se3_adjoint

CONVENTIONS = ("standard", "modified")
PARAMETER_NAMES = ("a", "alpha", "d", "theta_offset")
PRESETS = arm_presets()  # the tables in configs/robots

# unit screws (omega, v) of the four elementary motions
_SCREW = {
    "rz": np.array([0, 0, 1, 0, 0, 0.0]),
    "tz": np.array([0, 0, 0, 0, 0, 1.0]),
    "tx": np.array([0, 0, 0, 1, 0, 0.0]),
    "rx": np.array([1, 0, 0, 0, 0, 0.0]),
}
# the elementary motions of one link in product order, as (kind, column in the row (a, alpha, d, theta_offset))
_ORDER = {
    "standard": (("rz", 3), ("tz", 2), ("tx", 0), ("rx", 1)),
    "modified": (("rx", 1), ("tx", 0), ("rz", 3), ("tz", 2)),
}


def _elementary(kind: str, value: float) -> np.ndarray:
    T = np.eye(4)
    if kind in ("rz", "rx"):
        c, s = np.cos(value), np.sin(value)
        if kind == "rz":
            T[:2, :2] = [[c, -s], [s, c]]
        else:
            T[1:3, 1:3] = [[c, -s], [s, c]]
    elif kind == "tz":
        T[2, 3] = value
    else:
        T[0, 3] = value
    return T


@dataclass(frozen=True)
class DHChain:
    """A serial arm of revolute joints: ``dh`` (n, 4) rows ``(a [m], alpha [rad], d [m], theta_offset [rad])``.

    ``joint_limits_rad`` (n, 2) bounds the encoder angles ``q`` (None: unbounded). ``error_prior``:
    how far the real arm may be from this table, ``(length sigma [m], angle sigma [rad], encoder sigma
    [rad])`` per DH parameter and joint (the preset's ``error_prior``; None: not stated). ``home_rad`` (n,):
    the configuration the arm works about (the preset's ``home``), which picks among the inverse
    kinematics' configurations of a pose (None: not stated).
    """

    name: str
    convention: str
    dh: np.ndarray  # shape (n, 4)
    joint_limits_rad: Optional[np.ndarray] = None  # shape (n, 2)
    error_prior: Optional[tuple] = None  # (length sigma m, angle sigma rad, encoder sigma rad)
    home_rad: Optional[np.ndarray] = None  # shape (n,)

    def __post_init__(self):
        if self.convention not in CONVENTIONS:
            raise ConfigError(
                f"unknown DH convention of {self.name!r}",
                expected=" | ".join(CONVENTIONS),
                received=repr(self.convention),
            )
        dh = np.array(self.dh, float)
        if dh.ndim != 2 or dh.shape[1] != 4 or not np.all(np.isfinite(dh)) or len(dh) < 1:
            raise ConfigError(
                f"invalid DH table of {self.name!r}",
                expected="n rows (a, alpha, d, theta_offset)",
                received=f"array of shape {dh.shape}",
            )
        dh.setflags(write=False)
        object.__setattr__(self, "dh", dh)
        if self.joint_limits_rad is not None:
            lim = np.array(self.joint_limits_rad, float)
            if lim.shape != (len(dh), 2) or np.any(lim[:, 0] >= lim[:, 1]):
                raise ConfigError(
                    f"invalid joint limits of {self.name!r}",
                    expected=f"({len(dh)}, 2) low < high",
                    received=repr(lim.tolist()),
                )
            lim.setflags(write=False)
            object.__setattr__(self, "joint_limits_rad", lim)
        if self.home_rad is not None:
            home = np.array(self.home_rad, float).reshape(-1)
            if home.shape != (len(dh),) or not np.all(np.isfinite(home)):
                raise ConfigError(
                    f"invalid home configuration of {self.name!r}",
                    expected=f"{len(dh)} joint angles",
                    received=repr(home.tolist()),
                )
            home.setflags(write=False)
            object.__setattr__(self, "home_rad", home)

    @property
    def n_joints(self) -> int:
        return int(self.dh.shape[0])

    @property
    def reach_m(self) -> float:
        """Upper bound of the flange's distance from the first joint's axis point.

        The sum of |a| and of |d| after joint 1.
        """
        d = self.dh[:, 2].copy()
        d[0] = 0.0
        return float(np.sum(np.abs(self.dh[:, 0])) + np.sum(np.abs(d)))

    def with_dh(self, dh: np.ndarray, *, name: Optional[str] = None) -> "DHChain":
        """The same arm with another DH table (e.g. a perturbed one)."""
        return replace(self, dh=np.asarray(dh, float), name=self.name if name is None else name)

    def within_limits(self, joints: np.ndarray) -> bool:
        if self.joint_limits_rad is None:
            return True
        q = np.asarray(joints, float)
        return bool(np.all(q >= self.joint_limits_rad[:, 0]) and np.all(q <= self.joint_limits_rad[:, 1]))

    # ---------------------------------------------------------------------------------------
    def _factors(self, joints: np.ndarray) -> list:
        """[(kind, T)] of the 4n elementary motions in product order."""
        q = np.asarray(joints, float).reshape(-1)
        if q.shape != (self.n_joints,):
            raise ValueError(f"{self.name}: expected {self.n_joints} joint angles, got {q.shape[0]}")
        out = []
        for i in range(self.n_joints):
            row = self.dh[i].copy()
            row[3] += q[i]
            for kind, col in _ORDER[self.convention]:
                out.append((kind, _elementary(kind, row[col])))
        return out

    def _links(self, joints: np.ndarray) -> np.ndarray:
        """(n,4,4) link transforms T_{i-1,i} in closed form (the product of each row's four factors)."""
        q = np.asarray(joints, float)
        if q.shape[-1:] != (self.n_joints,):
            raise ValueError(f"{self.name}: expected {self.n_joints} joint angles, got {q.shape[-1:]}")
        a, al, d = self.dh[:, 0], self.dh[:, 1], self.dh[:, 2]
        th = self.dh[:, 3] + q
        ct, st = np.cos(th), np.sin(th)
        ca, sa = np.broadcast_to(np.cos(al), th.shape), np.broadcast_to(np.sin(al), th.shape)
        a, d = np.broadcast_to(a, th.shape), np.broadcast_to(d, th.shape)
        T = np.zeros(th.shape + (4, 4))
        T[..., 3, 3] = 1.0
        if self.convention == "standard":  # Rz(theta) Tz(d) Tx(a) Rx(alpha)
            T[..., 0, 0], T[..., 0, 1], T[..., 0, 2], T[..., 0, 3] = ct, -st * ca, st * sa, a * ct
            T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = st, ct * ca, -ct * sa, a * st
            T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = sa, ca, d
        else:  # Rx(alpha) Tx(a) Rz(theta) Tz(d)
            T[..., 0, 0], T[..., 0, 1], T[..., 0, 3] = ct, -st, a
            T[..., 1, 0], T[..., 1, 1], T[..., 1, 2], T[..., 1, 3] = st * ca, ct * ca, -sa, -sa * d
            T[..., 2, 0], T[..., 2, 1], T[..., 2, 2], T[..., 2, 3] = st * sa, ct * sa, ca, ca * d
        return T

    def _frames(self, joints: np.ndarray) -> np.ndarray:
        """(..., n+1, 4, 4): the DH frames 0..n in the base frame for joint angles (..., n)."""
        links = self._links(joints)
        frames = np.empty(links.shape[:-3] + (self.n_joints + 1, 4, 4))
        frames[..., 0, :, :] = np.eye(4)
        for i in range(self.n_joints):
            frames[..., i + 1, :, :] = frames[..., i, :, :] @ links[..., i, :, :]
        return frames

    def T_base_end(self, joints: np.ndarray) -> np.ndarray:
        """Flange pose (4,4) for joint angles (n,), or (N,4,4) for (N,n)."""
        q = np.asarray(joints, float)
        if q.ndim == 2:
            return np.stack([self.T_base_end(qi) for qi in q]) if len(q) else np.zeros((0, 4, 4))
        T = np.eye(4)
        for L in self._links(q):
            T = T @ L
        return T

    def _screw_columns(self, joints: np.ndarray, *, only_kind: Optional[str] = None) -> np.ndarray:
        """(6, 4n) body-frame columns of every elementary motion, in product order.

        (6, 4n) body-frame columns of every elementary motion, in product order (zeros for the
        motions of another kind than ``only_kind`` when it is given).
        """
        factors = self._factors(joints)
        cols = np.zeros((6, len(factors)))
        suffix = np.eye(4)  # product of the factors after k
        for k in range(len(factors) - 1, -1, -1):
            kind, F = factors[k]
            if only_kind is None or kind == only_kind:
                cols[:, k] = se3_adjoint(inv_T(suffix)) @ _SCREW[kind]
            suffix = F @ suffix
        return cols

    def jacobian_joints(self, joints: np.ndarray) -> np.ndarray:
        """(6, n): ``T_base_end(q + dq) ≈ T_base_end(q) · Exp(J dq)`` (right tangent, (omega, v)).

        Joint i turns about the z axis of the frame before its link (standard) or after it (modified; the
        Tz(d) that follows moves along that axis): the unit twist ``(z, p x z)`` in the base frame,
        carried to the end frame by ``Ad(inv(T_base_end))``.
        """
        return self._jacobian_joints_frames(self._frames(joints))

    def _jacobian_joints_frames(self, frames: np.ndarray) -> np.ndarray:
        """:meth:`jacobian_joints` from the DH frames (..., n+1, 4, 4) -> (..., 6, n)."""
        axes = frames[..., :-1, :, :] if self.convention == "standard" else frames[..., 1:, :, :]
        z, p = axes[..., :3, 2], axes[..., :3, 3]  # shape (..., n, 3)
        t = frames[..., -1, None, :3, 3]
        # Ad(inv(T_base_end)) (z, p x z) = (R^T z, R^T ((p - t) x z)), (rotation, translation)
        RT = np.swapaxes(frames[..., -1, :3, :3], -1, -2)
        w = np.einsum("...ij,...nj->...in", RT, z)
        v = np.einsum("...ij,...nj->...in", RT, np.cross(p - t, z))
        return np.concatenate([w, v], axis=-2)

    def jacobian_dh(self, joints: np.ndarray) -> np.ndarray:
        """(6, 4n): the same for the DH parameters, columns ``(a_1, alpha_1, d_1, theta_offset_1, a_2, ...)``."""
        cols = self._screw_columns(joints)
        out = np.empty_like(cols)
        for i in range(self.n_joints):
            for j, (_, col) in enumerate(_ORDER[self.convention]):
                out[:, 4 * i + col] = cols[:, 4 * i + j]
        return out


def T_base_end(chain: DHChain, joints: np.ndarray) -> np.ndarray:
    """``chain.T_base_end(joints)``: the flange pose of ``chain`` at ``joints`` (radians)."""
    return chain.T_base_end(joints)


# ---------------------------------------------------------------------------------------------
# Inverse kinematics (numeric; for the simulator and for checks, not for motion planning)
# ---------------------------------------------------------------------------------------------


def _wrap(q: np.ndarray) -> np.ndarray:
    return (np.asarray(q, float) + np.pi) % (2 * np.pi) - np.pi


def _pose_error(T: np.ndarray, T_target: np.ndarray) -> np.ndarray:
    """``(rotation vector of R^T R_target, R^T (t_target - t))`` (..., 6) of poses T.

    ``(rotation vector of R^T R_target, R^T (t_target - t))`` (..., 6) of poses T (..., 4, 4): zero exactly
    when the poses agree, the right-tangent difference to first order (cheaper than
    :func:`handeye.frames.tangent_difference`).
    """
    RT = np.swapaxes(T[..., :3, :3], -1, -2)
    R = RT @ T_target[:3, :3]
    w = 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.linalg.norm(w, axis=-1)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    # angle / sin(angle) from atan2 below 90 deg (1 + s^2 / 6 near 0); the general log beyond
    scale = np.where(s > 1e-8, np.arctan2(s, c) / np.maximum(s, 1e-300), 1.0 + s * s / 6.0)
    rot = w * scale[..., None]
    far = c <= 0.0
    if np.any(far):
        rot[far] = rotvec_from_R(R[far])
    v = np.einsum("...ij,...j->...i", RT, T_target[:3, 3] - T[..., :3, 3])
    return np.concatenate([rot, v], axis=-1)


def solve_ik(
    chain: DHChain,
    T_base_end_target: np.ndarray,
    *,
    seeds: Sequence[np.ndarray],
    damping: float = 1e-3,
    max_iterations: int = 100,
    nearest: Optional[np.ndarray] = None,
) -> Optional[np.ndarray]:
    """Joint angles (n,) whose flange pose is ``T_base_end_target``, within the joint limits, or None.

    Damped least squares (Levenberg-Marquardt on the right tangent of the pose) from every seed at
    once (a seed still further than ~1 mm / 0.06 deg after 12 steps is dropped if another is nearer, a pose
    far from every seed taking the slow ones longer); the solution of the
    first seed whose pose error is below ~1e-9 (rad and m) and whose angles (wrapped to (-pi, pi]) lie
    within the limits is returned, or with ``nearest`` (n,) (also a seed) the solution nearest those joint
    angles (the largest wrapped joint difference): one configuration of the arm among those reaching the pose.
    """
    T_target = np.asarray(T_base_end_target, float)
    seeds = ([nearest] if nearest is not None else []) + list(seeds)  # the nearest configuration is a seed too
    Q = np.array([np.asarray(q0, float).reshape(-1) for q0 in seeds])
    if not len(Q):
        return None
    S = len(Q)
    lam = np.full(S, float(damping))
    err = _pose_error(chain._frames(Q)[:, -1], T_target)
    cost = np.einsum("si,si->s", err, err)
    alive = np.ones(S, bool)
    eye6 = np.eye(6)
    for it in range(max_iterations):
        if it == 12 and np.any(cost <= 1e-6):
            alive &= cost <= 1e-6  # far after 12 steps while another seed is near: dropped
        run = np.flatnonzero(alive & (cost >= 1e-18))
        if not run.size:
            break
        J = chain._jacobian_joints_frames(chain._frames(Q[run]))  # shape (r, 6, n)
        A = J @ np.swapaxes(J, 1, 2) + lam[run, None, None] * eye6
        dq = np.einsum("rji,rj->ri", J, np.linalg.solve(A, err[run][..., None])[..., 0])
        Q_new = Q[run] + dq
        err_new = _pose_error(chain._frames(Q_new)[:, -1], T_target)
        cost_new = np.einsum("si,si->s", err_new, err_new)
        better = cost_new < cost[run]
        up = run[better]
        Q[up], err[up], cost[up] = Q_new[better], err_new[better], cost_new[better]
        lam[up] = np.maximum(lam[up] * 0.1, 1e-12)
        worse = run[~better]
        lam[worse] *= 10.0
        alive[worse[lam[worse] > 1e6]] = False
    found = [qw for qw in (_wrap(Q[k]) for k in np.flatnonzero(cost < 1e-18)) if chain.within_limits(qw)]
    if not found or nearest is None:
        return found[0] if found else None
    ref = np.asarray(nearest, float).reshape(-1)
    return min(found, key=lambda q: float(np.max(np.abs(_wrap(q - ref)))))


def default_ik_seeds(chain: DHChain, T_base_end_target: np.ndarray) -> list:
    """A few deterministic starting configurations.

    Joint 1 turned towards the target, shoulder, elbow and wrist in several bends.
    """
    p = np.asarray(T_base_end_target, float)[:3, 3]
    base = float(np.arctan2(p[1], p[0]))
    seeds = []
    for b in (base, base + np.pi):
        for s2 in (-0.6, 0.6):
            for s3 in (-1.2, 1.2):
                for s5 in (-0.8, 0.8):
                    q = np.zeros(chain.n_joints)
                    q[0] = b
                    if chain.n_joints >= 3:
                        q[1], q[2] = s2, s3
                    if chain.n_joints >= 5:
                        q[4] = s5
                    seeds.append(_wrap(q))
    return seeds


# ---------------------------------------------------------------------------------------------
# Presets
# ---------------------------------------------------------------------------------------------

_LENGTH = {"m": 1.0, "mm": 1e-3}
_ANGLE = {"rad": 1.0, "deg": np.pi / 180.0}
# spellings of the units other tools write in their tables (``units: {length: metres, angle: degrees}``)
_UNIT_NAMES = {
    "meter": "m",
    "meters": "m",
    "metre": "m",
    "metres": "m",
    "millimeter": "mm",
    "millimeters": "mm",
    "millimetre": "mm",
    "millimetres": "mm",
    "radian": "rad",
    "radians": "rad",
    "degree": "deg",
    "degrees": "deg",
}


def _field(data: dict, names: tuple, source: str, default=None):
    """The value of the one key of ``names`` (synonyms of one field) that ``data`` holds, else ``default``."""
    given = [k for k in names if k in data]
    if len(given) > 1:
        raise ConfigError(
            f"DH table states both {given[0]} and {given[1]}",
            path=source,
            expected=f"one of {', '.join(names)}",
            received=", ".join(given),
        )
    return data[given[0]] if given else default


def _units(data: dict, source: str) -> tuple:
    """(length unit, angle unit) of a table: ``length_unit`` / ``angle_unit``, or a ``units: {length, angle}`` block."""
    block = data.get("units")
    if block is not None and ("length_unit" in data or "angle_unit" in data):
        raise ConfigError(
            "DH table states its units twice",
            path=source,
            expected="units: {length, angle} or length_unit / angle_unit",
            received="both",
        )
    if block is not None and not isinstance(block, dict):
        raise ConfigError(
            "DH table units must be a mapping",
            path=source,
            expected="units: {length: m, angle: rad}",
            received=repr(block)[:60],
        )
    lu, au = (
        (block.get("length", "m"), block.get("angle", "rad"))
        if block is not None
        else (data.get("length_unit", "m"), data.get("angle_unit", "rad"))
    )
    lu, au = (_UNIT_NAMES.get(str(u).lower(), str(u).lower()) for u in (lu, au))
    if lu not in _LENGTH or au not in _ANGLE:
        raise ConfigError(
            "unknown unit in DH table", path=source, expected="length m|mm, angle rad|deg", received=f"{lu!r}, {au!r}"
        )
    return lu, au


def chain_from_dict(data: dict, *, source: str = "DH table") -> DHChain:
    """A :class:`DHChain` from a table in either form:

    * the presets' (``name``, ``convention``, ``length_unit``, ``angle_unit``,
      ``links: [{a, alpha, d, theta_offset, limits}]``, ``error_prior``);
    * the JSON form other tools write (``robot_name``, ``dh_convention``, ``units: {length, angle}``,
      ``joints: [{a, alpha, d, theta_offset}]``, optionally ``degrees_of_freedom``).

    Units m | mm and rad | deg (or their spelled-out names); the keys of the two forms may be mixed,
    but one field stated twice is an error.
    """
    if not isinstance(data, dict):
        raise ConfigError(
            "a DH table must be a mapping",
            path=source,
            expected="name, convention, links",
            received=type(data).__name__,
        )
    lu, au = _units(data, source)
    links = _field(data, ("links", "joints"), source)
    if not isinstance(links, list) or not links:
        raise ConfigError(
            "DH table without links",
            path=source,
            expected="links (or joints): a list of rows",
            received=repr(links)[:80],
        )
    dof = data.get("degrees_of_freedom")
    if dof is not None and dof != len(links):
        raise ConfigError(
            "DH table rows do not match its degrees_of_freedom",
            path=source,
            expected=f"{dof} rows",
            received=f"{len(links)} rows",
        )
    rows, limits = [], []
    for i, link in enumerate(links, start=1):
        missing = [k for k in PARAMETER_NAMES if not isinstance(link, dict) or k not in link]
        if missing:
            raise ConfigError(
                f"DH row {i} lacks {', '.join(missing)}",
                path=source,
                expected="a, alpha, d, theta_offset",
                received=repr(link),
            )
        try:
            rows.append(
                [
                    float(link["a"]) * _LENGTH[lu],
                    float(link["alpha"]) * _ANGLE[au],
                    float(link["d"]) * _LENGTH[lu],
                    float(link["theta_offset"]) * _ANGLE[au],
                ]
            )
            lim = link.get("limits")
            limits.append(None if lim is None else [float(lim[0]) * _ANGLE[au], float(lim[1]) * _ANGLE[au]])
        except (TypeError, ValueError, IndexError):
            raise ConfigError(
                f"DH row {i} is not numeric", path=source, expected="numbers", received=repr(link)
            ) from None
    lim = None if any(x is None for x in limits) else np.array(limits)
    name = _field(data, ("name", "robot_name"), source, default=source)
    return DHChain(
        name=str(name),
        convention=str(_field(data, ("convention", "dh_convention"), source, default="")),
        dh=np.array(rows),
        joint_limits_rad=lim,
        error_prior=_error_prior(data.get("error_prior"), source),
        home_rad=_home(data.get("home"), len(rows), au, source),
    )


def _home(home: Any, n: int, angle_unit: str, source: str) -> Optional[np.ndarray]:
    """``home: [q_1, ...]`` (the table's angle unit) in radians, or None."""
    if home is None:
        return None
    try:
        q = np.array(home, float).reshape(-1) * _ANGLE[angle_unit]
    except (TypeError, ValueError):
        q = np.zeros(0)
    if q.shape != (n,) or not np.all(np.isfinite(q)):
        raise ConfigError(
            "invalid home of the DH table", path=source, expected=f"{n} joint angles", received=repr(home)[:80]
        )
    return q


def chain_to_dict(chain: DHChain) -> dict:
    """The table of ``chain`` in the presets' form, metres and radians.

    The table of ``chain`` in the presets' form, metres and radians (:func:`chain_from_dict` reads it back;
    the error prior is not part of it): a result records the arm it was calibrated with.
    """
    lim = chain.joint_limits_rad
    links: list[dict[str, Any]] = [
        dict(zip(PARAMETER_NAMES, (float(v) for v in row), strict=False)) for row in np.asarray(chain.dh, float)
    ]
    if lim is not None:
        for link, (lo, hi) in zip(links, np.asarray(lim, float), strict=False):
            link["limits"] = [float(lo), float(hi)]
    out: dict[str, Any] = {"name": chain.name, "convention": chain.convention, "length_unit": "m", "angle_unit": "rad"}
    out["links"] = links
    if chain.home_rad is not None:
        out["home"] = [float(v) for v in chain.home_rad]
    return out


def _error_prior(d, source: str) -> Optional[tuple]:
    """``error_prior: {dh_length_sigma_mm, dh_angle_sigma_deg, encoder_sigma_deg}`` in SI, or None."""
    if d is None:
        return None
    keys = ("dh_length_sigma_mm", "dh_angle_sigma_deg", "encoder_sigma_deg")
    try:
        vals = [float(d[k]) for k in keys]
    except (TypeError, KeyError, ValueError):
        raise ConfigError(
            "invalid error_prior of the DH table",
            path=source,
            expected=", ".join(keys) + " (numbers)",
            received=repr(d)[:80],
        ) from None
    if not all(np.isfinite(v) and v > 0 for v in vals):
        raise ConfigError("error_prior sigmas must be positive", path=source, received=repr(vals))
    return (vals[0] * 1e-3, float(np.radians(vals[1])), float(np.radians(vals[2])))


def load_arm(name_or_path: Union[str, Path, dict], *, folder: Optional[Path] = None) -> DHChain:
    """A DH chain from a shipped preset, a DH table file or the table itself.

    A shipped preset (:data:`PRESETS`: ``rm65``, ``ur5e``, ...), a DH table file in either form of
    :func:`chain_from_dict` (``.json`` read as JSON, anything else as YAML; relative paths from ``folder`` when given,
    e.g. a session's ``robot:``), or the table itself as a mapping. A file that cannot be read or parsed is a
    ConfigError naming it.
    """
    import json

    import yaml

    from .config import load_preset

    if isinstance(name_or_path, dict):
        return chain_from_dict(name_or_path, source="robot (DH table)")
    key = str(name_or_path)
    if key in PRESETS:
        return chain_from_dict(load_preset(f"robots/{key}"), source=f"configs/robots/{key}.yaml")
    path = Path(key) if folder is None or Path(key).is_absolute() else Path(folder) / key
    if not path.is_file():
        raise ConfigError(
            "unknown robot model",
            expected=f"a preset ({', '.join(PRESETS)}) or a DH table file (YAML or JSON)",
            received=repr(key),
        )
    is_json = path.suffix.lower() == ".json"
    try:
        text = path.read_text(encoding="utf-8")
        data = json.loads(text) if is_json else yaml.safe_load(text)
    except (OSError, UnicodeDecodeError, ValueError, yaml.YAMLError) as e:  # json's errors are ValueErrors
        mark = getattr(e, "problem_mark", None)  # YAML's (0-based)
        line = e.lineno if isinstance(e, json.JSONDecodeError) else None if mark is None else mark.line + 1
        raise ConfigError(
            "cannot read the DH table",
            path=path,
            line=line,
            expected="a JSON file" if is_json else "a YAML file",
            received=f"{type(e).__name__}: {clip(str(e).splitlines()[0], 80)}",
        ) from None
    return chain_from_dict(data, source=str(path))
