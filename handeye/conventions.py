"""External pose conventions, translated once at the boundary.

Everything inside handeye is a 4x4 ``T_a_b``. This module is the only place that knows about
Euler angles, quaternion orders, millimetres and the vendor's pose lines. The table in
``docs/conventions.md`` lists each external convention and its translation.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .errors import ConfigError
from .frames import is_rotation, make_T


def _Rotation():
    """Scipy's Rotation, imported on first use (Euler sequences of every order live only at this boundary)."""
    from scipy.spatial.transform import Rotation

    return Rotation


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


def _scipy_euler_seq(fmt: PoseFormat) -> str:
    # scipy: lower case = extrinsic, upper case = intrinsic; angles listed in the same order.
    return fmt.euler_order.lower() if fmt.euler_kind == "extrinsic" else fmt.euler_order.upper()


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
        R = _Rotation().from_euler(_scipy_euler_seq(fmt), r, degrees=fmt.angle_unit == "deg").as_matrix()
    elif fmt.rotation == "rotvec":
        rv = np.radians(r) if fmt.angle_unit == "deg" else r
        R = _Rotation().from_rotvec(rv).as_matrix()
    else:
        q = r if fmt.quaternion_order == "xyzw" else r[[1, 2, 3, 0]]
        n = np.linalg.norm(q)
        if abs(n - 1.0) > 1e-3:
            raise ValueError(f"quaternion norm is {n:.6f}, expected 1 (check the quaternion order)")
        R = _Rotation().from_quat(q / n).as_matrix()
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
    rot = _Rotation().from_matrix(T[:3, :3])
    if fmt.rotation == "euler":
        r = rot.as_euler(_scipy_euler_seq(fmt), degrees=fmt.angle_unit == "deg")
    elif fmt.rotation == "rotvec":
        r = rot.as_rotvec()
        r = np.degrees(r) if fmt.angle_unit == "deg" else r
    else:
        q = rot.as_quat()  # xyzw
        q = q if q[3] >= 0 else -q
        r = q if fmt.quaternion_order == "xyzw" else q[[3, 0, 1, 2]]
    return np.concatenate([t, r])


def vendor_euler_from_R(R: np.ndarray) -> np.ndarray:
    """(rx, ry, rz) radians with R = Rz(rz)·Ry(ry)·Rx(rx), the vendor's convention."""
    return _Rotation().from_matrix(np.asarray(R, float)).as_euler("xyz")


def pose_forms(T_a_b: np.ndarray) -> dict:
    """A transform in every form a robot programmer asks for (used by result.json and reports)."""
    T = np.asarray(T_a_b, float)
    rot = _Rotation().from_matrix(T[:3, :3])
    q = rot.as_quat()
    q = q if q[3] >= 0 else -q
    rv = rot.as_rotvec()
    eul = vendor_euler_from_R(T[:3, :3])
    return {
        "matrix": T.tolist(),
        "translation_mm": (T[:3, 3] * 1e3).tolist(),
        "quaternion_wxyz": [float(q[3]), float(q[0]), float(q[1]), float(q[2])],
        "rotvec_rad": rv.tolist(),
        "rotvec_deg": np.degrees(rv).tolist(),
        "euler_vendor_rad": eul.tolist(),
        "euler_vendor_deg": np.degrees(eul).tolist(),
        "euler_vendor_convention": "rx, ry, rz with R = Rz(rz) @ Ry(ry) @ Rx(rx) (extrinsic x-y-z)",
        "vendor_pose_line": ",".join(f"{x:.6f}" for x in np.concatenate([T[:3, 3], eul])),
    }
