import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from handeye.conventions import VENDOR_POSE_FORMAT, PoseFormat, T_from_pose_values, pose_forms, pose_values_from_T
from handeye.errors import ConfigError
from handeye.frames import inv_T, make_T, mean_T, pose_error, quat_wxyz_from_R


def Rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def Ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def Rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_vendor_euler_is_Rz_Ry_Rx_written_out():
    rx, ry, rz = 0.3, -0.7, 2.1
    T = T_from_pose_values([0.1, -0.2, 0.3, rx, ry, rz], VENDOR_POSE_FORMAT)
    np.testing.assert_allclose(T[:3, :3], Rz(rz) @ Ry(ry) @ Rx(rx), atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [0.1, -0.2, 0.3])


def test_vendor_euler_differs_from_the_other_order():
    T = T_from_pose_values([0, 0, 0, 0.3, -0.7, 2.1], VENDOR_POSE_FORMAT)
    assert not np.allclose(T[:3, :3], Rx(0.3) @ Ry(-0.7) @ Rz(2.1), atol=1e-3)


FORMATS = [
    PoseFormat(),
    PoseFormat(euler_order="zyx", euler_kind="intrinsic", angle_unit="deg", translation_unit="mm"),
    PoseFormat(euler_order="zyz", euler_kind="extrinsic"),
    PoseFormat(rotation="quaternion", quaternion_order="wxyz"),
    PoseFormat(rotation="quaternion", quaternion_order="xyzw", translation_unit="mm"),
    PoseFormat(rotation="rotvec"),
    PoseFormat(rotation="rotvec", angle_unit="deg"),
    PoseFormat(rotation="rotvec", translation_unit="cm"),
    PoseFormat(rotation="matrix", translation_unit="mm"),
]


def test_centimetres_are_a_translation_unit():
    T = T_from_pose_values([12.5, -3.0, 40.0, 0, 0, 0], PoseFormat(translation_unit="cm").validated())
    assert np.allclose(T[:3, 3], [0.125, -0.03, 0.4])
    with pytest.raises(ConfigError, match="translation_unit"):
        PoseFormat(translation_unit="in").validated()


@pytest.mark.parametrize("fmt", FORMATS, ids=lambda f: f.describe())
def test_every_pose_format_round_trips(fmt):
    rng = np.random.default_rng(1)
    for _ in range(20):
        T = make_T(Rotation.random(random_state=rng.integers(1 << 31)).as_matrix(), rng.uniform(-0.8, 0.8, 3))
        back = T_from_pose_values(pose_values_from_T(T, fmt), fmt.validated())
        r, t = pose_error(back, T)
        assert r < 1e-9 and t < 1e-9, (fmt, r, t)


def test_intrinsic_zyx_equals_extrinsic_xyz_reversed():
    a = [0.2, -0.4, 1.0]
    T1 = T_from_pose_values([0, 0, 0, *a], PoseFormat(euler_order="xyz", euler_kind="extrinsic"))
    T2 = T_from_pose_values([0, 0, 0, *a[::-1]], PoseFormat(euler_order="zyx", euler_kind="intrinsic"))
    np.testing.assert_allclose(T1, T2, atol=1e-12)


def test_quaternion_orders_differ_and_are_checked():
    q_wxyz = quat_wxyz_from_R(Rx(0.5))
    T = T_from_pose_values([0, 0, 0, *q_wxyz], PoseFormat(rotation="quaternion", quaternion_order="wxyz"))
    np.testing.assert_allclose(T[:3, :3], Rx(0.5), atol=1e-12)
    with pytest.raises(ValueError, match="norm"):
        T_from_pose_values([0, 0, 0, 1, 1, 0, 0], PoseFormat(rotation="quaternion"))


def test_bad_values_raise():
    with pytest.raises(ValueError, match="NaN"):
        T_from_pose_values([0, 0, np.nan, 0, 0, 0], VENDOR_POSE_FORMAT)
    with pytest.raises(ValueError, match="expected 6"):
        T_from_pose_values([0, 0, 0, 0, 0], VENDOR_POSE_FORMAT)
    M = np.eye(4)
    M[0, 0] = 2
    with pytest.raises(ValueError, match="not a rotation"):
        T_from_pose_values(M.reshape(-1), PoseFormat(rotation="matrix"))


@pytest.mark.parametrize(
    "field,value",
    [
        ("rotation", "euler2"),
        ("euler_order", "xxy"),
        ("angle_unit", "grad"),
        ("quaternion_order", "wzyx"),
        ("translation_unit", "inch"),
        ("euler_kind", "both"),
    ],
)
def test_pose_format_validation_names_the_field(field, value):
    with pytest.raises(ConfigError, match=field):
        PoseFormat(**{field: value}).validated()


def test_pose_forms_are_consistent():
    T = T_from_pose_values([0.1, 0.2, 0.3, 0.4, -0.5, 0.6], VENDOR_POSE_FORMAT)
    f = pose_forms(T)
    assert np.allclose(f["translation_mm"], [100, 200, 300])
    back = T_from_pose_values([float(x) for x in f["vendor_pose_line"].split(",")], VENDOR_POSE_FORMAT)
    r_deg, t_mm = pose_error(back, T)
    assert r_deg < 1e-4 and t_mm < 1e-3  # the line is printed to 1e-6 (m, rad): <= 5.7e-5 deg, 5e-4 mm
    w, x, y, z = f["quaternion_wxyz"]
    assert w >= 0 and abs(w * w + x * x + y * y + z * z - 1) < 1e-12
    R_q = Rotation.from_quat([x, y, z, w]).as_matrix()
    np.testing.assert_allclose(R_q, T[:3, :3], atol=1e-12)
    np.testing.assert_allclose(Rotation.from_rotvec(f["rotvec_rad"]).as_matrix(), T[:3, :3], atol=1e-12)
    np.testing.assert_allclose(np.degrees(f["rotvec_rad"]), f["rotvec_deg"], atol=1e-12)


def test_inverse_and_mean():
    rng = np.random.default_rng(0)
    T = make_T(Rotation.random(random_state=3).as_matrix(), rng.normal(size=3))
    np.testing.assert_allclose(inv_T(T) @ T, np.eye(4), atol=1e-12)
    # rotations R·Exp(±w) and translations t ± dt (0.37 rad, 5.4 cm each way) average back to T,
    # and to neither of them
    Rd = Rotation.from_rotvec([0.3, -0.1, 0.2]).as_matrix()
    dt = np.array([0.05, 0.0, -0.02])
    pair = np.stack([make_T(T[:3, :3] @ Rd, T[:3, 3] + dt), make_T(T[:3, :3] @ Rd.T, T[:3, 3] - dt)])
    m = mean_T(pair)
    np.testing.assert_allclose(m, T, atol=1e-12)
    assert min(pose_error(m, P)[0] for P in pair) > 10.0  # degrees away from each member


# ------------------------------------------------------------------------------ Euler angles without scipy.spatial
_SEQUENCES = [a + b + c for a in "xyz" for b in "xyz" for c in "xyz" if a != b and b != c]


@pytest.mark.parametrize("order", _SEQUENCES)
@pytest.mark.parametrize("intrinsic", [False, True])
def test_euler_conversions_equal_scipys(order, intrinsic):
    """Both directions against scipy's Rotation (the oracle), every order, gimbal lock included."""
    from handeye.conventions import R_from_euler, euler_from_R

    rng = np.random.default_rng(7)
    seq = order.upper() if intrinsic else order
    ang = rng.uniform(-np.pi, np.pi, (300, 3))
    repeated = order[0] == order[2]
    ang[:, 1] = rng.uniform(0, np.pi, 300) if repeated else rng.uniform(-np.pi / 2, np.pi / 2, 300)
    ang[:5, 1] = 0.0 if repeated else np.pi / 2  # gimbal lock: scipy sets the third angle to 0
    ang[5:10, 1] = np.pi if repeated else -np.pi / 2
    R = R_from_euler(ang, order=order, intrinsic=intrinsic)
    np.testing.assert_allclose(R, Rotation.from_euler(seq, ang).as_matrix(), rtol=0, atol=1e-14)
    with pytest.warns(UserWarning, match="Gimbal lock"):
        expected = Rotation.from_matrix(R).as_euler(seq)
    got = euler_from_R(R, order=order, intrinsic=intrinsic)
    np.testing.assert_allclose(np.angle(np.exp(1j * (got - expected))), 0.0, atol=1e-9)
    np.testing.assert_allclose(got[10:], expected[10:], rtol=0, atol=1e-12)  # away from the singularity
    np.testing.assert_array_equal(euler_from_R(R[20], order=order, intrinsic=intrinsic), got[20])  # one matrix


def test_euler_from_a_matrix_off_the_rotations_is_scipys():
    """A matrix that is not orthonormal is projected first, as scipy does."""
    from handeye.conventions import euler_from_R

    R = Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_matrix() * 1.001 + 1e-4
    np.testing.assert_allclose(
        euler_from_R(R, order="xyz", intrinsic=False), Rotation.from_matrix(R).as_euler("xyz"), atol=1e-12
    )


def test_degrees_are_converted():
    from handeye.conventions import R_from_euler

    np.testing.assert_allclose(
        R_from_euler([10.0, 20.0, 30.0], order="zyx", intrinsic=True, degrees=True),
        Rotation.from_euler("ZYX", [10.0, 20.0, 30.0], degrees=True).as_matrix(),
        atol=1e-15,
    )


def test_reading_poses_does_not_import_scipy_spatial():
    """The session readers and the result's pose forms stay off scipy.spatial (a start-up cost of every run)."""
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from handeye.conventions import T_from_pose_values, pose_forms, PoseFormat, VENDOR_POSE_FORMAT\n"
        "T = T_from_pose_values([0.1, 0.2, 0.3, 0.4, -0.5, 0.6], VENDOR_POSE_FORMAT)\n"
        "pose_forms(T)\n"
        "for r in ('rotvec', 'quaternion'):\n"
        "    f = PoseFormat(rotation=r)\n"
        "    T_from_pose_values([0, 0, 0, 1, 0, 0, 0][: f.n_values], f)\n"
        "print(sorted(m for m in sys.modules if m.startswith('scipy.spatial')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
