"""External pose conventions, translated once at the boundary.

Everything inside handeye is a 4x4 ``T_a_b``. This module is the only place that knows about
Euler angles, quaternion orders, millimetres and the vendor's pose lines. The table in
``docs/conventions.md`` lists each external convention and its translation.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .errors import ConfigError
from .frames import (
    R_from_quat_wxyz,
    R_from_rotvec,
    is_rotation,
    make_T,
    project_to_rotation,
    quat_wxyz_from_R,
    rotvec_from_R,
)

ROTATION_KINDS = ("euler", "quaternion", "rotvec", "matrix")
#: robot translation units a pose file may state -> metres per unit
TRANSLATION_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}
_AXES = set("xyz")


@dataclass(frozen=True)
class PoseFormat:
    """How one robot pose is written in a file.

    ``rotation``: euler | quaternion | rotvec | matrix.
    Euler: ``euler_order`` names the axis of each listed angle (e.g. "xyz" means the values are
    rx, ry, rz); ``euler_kind`` extrinsic (fixed axes) or intrinsic (moving axes);
    ``angle_unit`` rad or deg (also used for rotvec). Quaternion: ``quaternion_order`` wxyz or xyzw.
    ``translation_unit`` m, cm or mm (matrix translations too). Values are
    ``[x, y, z, <rotation...>]``; a matrix is 16 row-major values or a nested 4x4 list.
    """

    rotation: str = "euler"
    euler_order: str = "xyz"
    euler_kind: str = "extrinsic"
    angle_unit: str = "rad"
    quaternion_order: str = "wxyz"
    translation_unit: str = "m"

    def validated(self, *, source: str = "pose_format") -> "PoseFormat":
        def bad(field, expected, got):
            raise ConfigError(
                f"invalid {field} in {source}",
                expected=expected,
                received=repr(got),
                hint="fix the pose_format section of the session file",
            )

        if self.rotation not in ROTATION_KINDS:
            bad("rotation", " | ".join(ROTATION_KINDS), self.rotation)
        order = str(self.euler_order).lower()
        if len(order) != 3 or not set(order) <= _AXES or order[0] == order[1] or order[1] == order[2]:
            bad("euler_order", "three axes such as xyz, zyx or zyz", self.euler_order)
        if self.euler_kind not in ("extrinsic", "intrinsic"):
            bad("euler_kind", "extrinsic | intrinsic", self.euler_kind)
        if self.angle_unit not in ("rad", "deg"):
            bad("angle_unit", "rad | deg", self.angle_unit)
        if self.quaternion_order not in ("wxyz", "xyzw"):
            bad("quaternion_order", "wxyz | xyzw", self.quaternion_order)
        if self.translation_unit not in TRANSLATION_UNITS:
            bad("translation_unit", " | ".join(TRANSLATION_UNITS), self.translation_unit)
        return replace(self, euler_order=order)

    @property
    def n_values(self) -> int:
        return {"euler": 6, "quaternion": 7, "rotvec": 6, "matrix": 16}[self.rotation]

    def describe(self) -> str:
        if self.rotation == "euler":
            return f"x,y,z [{self.translation_unit}] + Euler {self.euler_kind} {self.euler_order} [{self.angle_unit}]"
        if self.rotation == "quaternion":
            return f"x,y,z [{self.translation_unit}] + quaternion {self.quaternion_order}"
        if self.rotation == "rotvec":
            return f"x,y,z [{self.translation_unit}] + rotation vector [{self.angle_unit}]"
        return f"4x4 matrix, translation in {self.translation_unit}"


#: The vendor's poses.txt: ``x,y,z,rx,ry,rz`` in metres and radians, R = Rz(rz)·Ry(ry)·Rx(rx).
VENDOR_POSE_FORMAT = PoseFormat(
    rotation="euler", euler_order="xyz", euler_kind="extrinsic", angle_unit="rad", translation_unit="m"
)


# ------------------------------------------------------------------------------ Euler angles
# Pure numpy, the algorithms of scipy.spatial.transform.Rotation (its from_euler / as_euler, Bernardes and
# Viollet 2022), equal to it within 1e-15; scipy.spatial is not imported: it costs about 0.1 s of CPU (0.3 s
# wall on a busy 2-core machine) of every calibration's start-up. Quaternions here are (w, x, y, z).
_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}


def _quat_product(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product ``p q`` of quaternions (..., 4) in (w, x, y, z) order."""
    pw, pv, qw, qv = p[..., :1], p[..., 1:], q[..., :1], q[..., 1:]
    return np.concatenate([pw * qw - np.sum(pv * qv, axis=-1, keepdims=True), pw * qv + qw * pv + np.cross(pv, qv)], -1)


def R_from_euler(angles, *, order: str, intrinsic: bool, degrees: bool = False) -> np.ndarray:
    """Rotation(s) (..., 3, 3) of Euler angles (..., 3) listed in the order of the axes ``order`` (e.g. "xyz").

    Extrinsic (fixed axes): R = R_order[2](a2) @ R_order[1](a1) @ R_order[0](a0); intrinsic (moving axes):
    R = R_order[0](a0) @ R_order[1](a1) @ R_order[2](a2). Scipy's ``Rotation.from_euler`` with ``order`` in
    lower case (extrinsic) or upper case (intrinsic).
    """
    a = np.asarray(angles, float)
    a = np.radians(a) if degrees else a
    q: np.ndarray | None = None
    for k, axis in enumerate(order.lower()):
        e = np.zeros((*a.shape[:-1], 4))
        e[..., 0] = np.cos(a[..., k] / 2.0)
        e[..., 1 + _AXIS_INDEX[axis]] = np.sin(a[..., k] / 2.0)
        q = e if q is None else (_quat_product(q, e) if intrinsic else _quat_product(e, q))
    assert q is not None, "an order has three axes"
    return R_from_quat_wxyz(q)


def euler_from_R(R, *, order: str, intrinsic: bool) -> np.ndarray:
    """Euler angles (..., 3) in radians of rotation(s) (..., 3, 3): the inverse of :func:`R_from_euler`.

    The middle angle in [0, pi] for repeated-axis orders (zyz), in [-pi/2, pi/2] otherwise, the others in
    (-pi, pi]; at gimbal lock (middle angle 0 or pi within 1e-7) the third angle is 0, as scipy's
    ``as_euler`` (which warns there; this does not). A matrix that is not orthonormal within 1e-12 is first
    projected onto the rotations, as scipy does.
    """
    R = np.asarray(R, float)
    gram = R @ np.swapaxes(R, -1, -2)
    if not np.allclose(gram, np.eye(3), rtol=0.0, atol=1e-12):
        R = project_to_rotation(R)
    qw = quat_wxyz_from_R(R)
    quat = qw[..., [1, 2, 3, 0]]  # x, y, z, w: scipy's indexing below
    axes = [_AXIS_INDEX[c] for c in order.lower()]
    i, j, k = axes if not intrinsic else axes[::-1]
    symmetric = i == k
    if symmetric:
        k = 3 - i - j
        a, b, c, d = quat[..., 3], quat[..., i], quat[..., j], quat[..., k] * ((i - j) * (j - k) * (k - i) // 2)
        sign = 1
    else:
        sign = (i - j) * (j - k) * (k - i) // 2
        a = quat[..., 3] - quat[..., j]
        b = quat[..., i] + quat[..., k] * sign
        c = quat[..., j] + quat[..., 3]
        d = quat[..., k] * sign - quat[..., i]
    extrinsic = not intrinsic
    half_sum, half_diff = np.arctan2(b, a), np.arctan2(d, c)
    out = np.zeros((*np.shape(a), 3))
    out[..., 1] = 2 * np.arctan2(np.hypot(c, d), np.hypot(a, b))
    first, third = (0, 2) if extrinsic else (2, 0)
    case1 = np.abs(out[..., 1]) <= 1e-7
    case2 = np.abs(out[..., 1] - np.pi) <= 1e-7
    case0 = ~(case1 | case2)
    out[..., 0] = np.where(case1, 2 * half_sum, 2 * half_diff * (-1 if extrinsic else 1))
    out[..., first] = np.where(case0, half_sum - half_diff, out[..., first])
    a3 = np.where(case0, half_sum + half_diff, out[..., third])
    if not symmetric:
        a3 = a3 * sign
        out[..., 1] -= np.pi / 2
    out[..., third] = a3
    return (out + np.pi) % (2 * np.pi) - np.pi


def T_from_pose_values(values, fmt: PoseFormat, *, rot_tol: float = 1e-4) -> np.ndarray:
    """4x4 ``T_base_end`` (metres) from a pose written in ``fmt``.

    Raises ValueError (callers add the file and line) on wrong counts, non-finite values or a
    matrix that is not a rotation.
    """
    v = np.asarray(values, dtype=float).reshape(-1)
    if v.size != fmt.n_values:
        raise ValueError(f"expected {fmt.n_values} numbers ({fmt.describe()}), got {v.size}")
    if not np.all(np.isfinite(v)):
        raise ValueError("pose contains NaN or infinite values")
    scale = TRANSLATION_UNITS.get(fmt.translation_unit, 1.0)
    if fmt.rotation == "matrix":
        T = v.reshape(4, 4).copy()
        if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
            transposed = np.allclose(T[:, 3], [0, 0, 0, 1], atol=1e-9)
            raise ValueError(
                f"last row of the 4x4 matrix must be 0 0 0 1, got {T[3].tolist()}"
                + (
                    " (the matrix looks transposed: write it row by row, translation in the last column)"
                    if transposed
                    else ""
                )
            )
        if not is_rotation(T[:3, :3], tol=rot_tol):
            raise ValueError("the 3x3 block is not a rotation (R^T R != I or det != 1)")
        T[:3, 3] *= scale
        return T
    t = v[:3] * scale
    r = v[3:]
    if fmt.rotation == "euler":
        R = R_from_euler(
            r, order=fmt.euler_order, intrinsic=fmt.euler_kind == "intrinsic", degrees=fmt.angle_unit == "deg"
        )
    elif fmt.rotation == "rotvec":
        rv = np.radians(r) if fmt.angle_unit == "deg" else r
        R = R_from_rotvec(rv)
    else:
        q = r if fmt.quaternion_order == "xyzw" else r[[1, 2, 3, 0]]
        n = np.linalg.norm(q)
        if abs(n - 1.0) > 1e-3:
            raise ValueError(f"quaternion norm is {n:.6f}, expected 1 (check the quaternion order)")
        R = R_from_quat_wxyz(q[[3, 0, 1, 2]] / n)
    return make_T(R, t)


def pose_values_from_T(T_base_end: np.ndarray, fmt: PoseFormat) -> np.ndarray:
    """Inverse of :func:`T_from_pose_values`: the numbers to write for ``T_base_end``."""
    T = np.asarray(T_base_end, float)
    scale = 1.0 / TRANSLATION_UNITS.get(fmt.translation_unit, 1.0)
    t = T[:3, 3] * scale
    if fmt.rotation == "matrix":
        out = T.copy()
        out[:3, 3] = t
        return out.reshape(-1)
    R = T[:3, :3]
    if fmt.rotation == "euler":
        r = euler_from_R(R, order=fmt.euler_order, intrinsic=fmt.euler_kind == "intrinsic")
        r = np.degrees(r) if fmt.angle_unit == "deg" else r
    elif fmt.rotation == "rotvec":
        r = rotvec_from_R(R)
        r = np.degrees(r) if fmt.angle_unit == "deg" else r
    else:
        q = quat_wxyz_from_R(R)  # w >= 0
        r = q if fmt.quaternion_order == "wxyz" else q[[1, 2, 3, 0]]
    return np.concatenate([t, r])


def vendor_euler_from_R(R: np.ndarray) -> np.ndarray:
    """(rx, ry, rz) radians with R = Rz(rz)·Ry(ry)·Rx(rx), the vendor's convention."""
    return euler_from_R(R, order="xyz", intrinsic=False)


def pose_forms(T_a_b: np.ndarray) -> dict:
    """A transform in every form a robot programmer asks for (used by result.json and reports)."""
    T = np.asarray(T_a_b, float)
    q = quat_wxyz_from_R(T[:3, :3])  # w >= 0
    rv = rotvec_from_R(T[:3, :3])
    eul = vendor_euler_from_R(T[:3, :3])
    return {
        "matrix": T.tolist(),
        "translation_mm": (T[:3, 3] * 1e3).tolist(),
        "quaternion_wxyz": [float(q[0]), float(q[1]), float(q[2]), float(q[3])],
        "rotvec_rad": rv.tolist(),
        "rotvec_deg": np.degrees(rv).tolist(),
        "euler_vendor_rad": eul.tolist(),
        "euler_vendor_deg": np.degrees(eul).tolist(),
        "euler_vendor_convention": "rx, ry, rz with R = Rz(rz) @ Ry(ry) @ Rx(rx) (extrinsic x-y-z)",
        "vendor_pose_line": ",".join(f"{x:.6f}" for x in np.concatenate([T[:3, 3], eul])),
    }
