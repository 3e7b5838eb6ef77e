"""Forward kinematics from DH tables: the shipped presets against their manufacturers' reference poses,
the Jacobians against central differences, inverse kinematics, and the loader's errors."""

import numpy as np
import pytest

from handeye.errors import ConfigError
from handeye.frames import se3_exp, tangent_difference
from handeye.kinematics import PRESETS, DHChain, chain_from_dict, chain_to_dict, default_ik_seeds, load_arm, solve_ik


def test_rm65_zero_configuration_stands_straight_up():
    # RealMan's MDH page: at zero joint angles the RM65 is upright; the flange sits d1 + a3 + d4 + d6 above the
    # base (240.5 + 256 + 210 + 144 mm for the RM65-B) with its z axis up, and a3 + d4 + d6 = 610 mm is the
    # published working radius.
    arm = load_arm("rm65")
    T = arm.T_base_end(np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [0.0, 0.0, 0.8505], atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], [0.0, 0.0, 1.0], atol=1e-12)
    assert arm.convention == "modified"
    assert arm.dh[2, 0] + arm.dh[3, 2] + arm.dh[5, 2] == pytest.approx(0.610)


def test_ur5e_zero_configuration_lies_along_minus_x():
    # Universal Robots' DH page: at zero the arm is stretched horizontally along -x; the flange is at
    # (a2 + a3, -(d4 + d6), d1 - d5) with its z axis along -y.
    arm = load_arm("ur5e")
    T = arm.T_base_end(np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [-0.8172, -0.2329, 0.0628], atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], [0.0, -1.0, 0.0], atol=1e-12)
    assert arm.convention == "standard"


def test_a_quarter_turn_of_joint_1_turns_the_flange_about_the_base_z():
    for name in PRESETS:
        arm = load_arm(name)
        q = np.array([0.3, -0.4, 0.5, 0.2, 0.6, -0.1])
        T0 = arm.T_base_end(q)
        T1 = arm.T_base_end(q + [np.pi / 2, 0, 0, 0, 0, 0])
        Rz = np.array([[0, -1, 0], [1, 0, 0], [0, 0, 1.0]])
        np.testing.assert_allclose(T1[:3, 3], Rz @ T0[:3, 3], atol=1e-12)
        np.testing.assert_allclose(T1[:3, :3], Rz @ T0[:3, :3], atol=1e-12)


@pytest.mark.parametrize("name", PRESETS)
def test_jacobians_match_central_differences(name):
    arm = load_arm(name)
    rng = np.random.default_rng(3)
    h = 1e-6
    for _ in range(3):
        q = rng.uniform(-1.5, 1.5, 6)
        T = arm.T_base_end(q)
        J_q = arm.jacobian_joints(q)
        for j in range(6):
            e = np.zeros(6)
            e[j] = h
            num = (tangent_difference(T, arm.T_base_end(q + e)) - tangent_difference(T, arm.T_base_end(q - e))) / (
                2 * h
            )
            np.testing.assert_allclose(J_q[:, j], num, atol=1e-8)
        J_dh = arm.jacobian_dh(q)
        assert J_dh.shape == (6, 24)
        for j in range(24):
            dh_p, dh_m = arm.dh.copy(), arm.dh.copy()
            dh_p.flat[j] += h
            dh_m.flat[j] -= h
            num = (
                tangent_difference(T, arm.with_dh(dh_p).T_base_end(q))
                - tangent_difference(T, arm.with_dh(dh_m).T_base_end(q))
            ) / (2 * h)
            np.testing.assert_allclose(J_dh[:, j], num, atol=1e-8)


def test_joint_jacobian_is_the_theta_offset_columns_and_predicts_a_small_motion():
    arm = load_arm("rm65")
    q = np.array([0.2, -0.3, 0.9, 0.1, -0.7, 0.4])
    J_q, J_dh = arm.jacobian_joints(q), arm.jacobian_dh(q)
    np.testing.assert_allclose(J_q, J_dh[:, 3::4], atol=1e-15)
    dq = np.radians([0.01, -0.02, 0.03, 0.01, 0.02, -0.01])
    predicted = arm.T_base_end(q) @ se3_exp(J_q @ dq)
    # first order: the rest is of order |dq|^2 ~ 3e-7
    np.testing.assert_allclose(predicted, arm.T_base_end(q + dq), atol=1e-6)


@pytest.mark.parametrize("name", PRESETS)
def test_inverse_kinematics_reaches_the_pose_within_the_limits(name):
    arm = load_arm(name)
    rng = np.random.default_rng(5)
    for _ in range(5):
        q = rng.uniform(-1.0, 1.0, 6)
        T = arm.T_base_end(q)
        sol = solve_ik(arm, T, seeds=default_ik_seeds(arm, T))
        assert sol is not None
        assert arm.within_limits(sol)
        np.testing.assert_allclose(arm.T_base_end(sol), T, atol=1e-9)


def test_inverse_kinematics_refuses_a_pose_out_of_reach():
    arm = load_arm("rm65")
    T = np.eye(4)
    T[:3, 3] = [1.5, 0.0, 0.3]
    assert solve_ik(arm, T, seeds=default_ik_seeds(arm, T)) is None


def test_inverse_kinematics_does_not_drop_every_seed_of_a_pose_far_from_them_all():
    """A kinematic session's views one by one, as calibrate --robot solves a vendor folder without joint angles:
    view 19 of this one is more than 1 mm from every seed after 12 steps, yet reachable (the arm was there).
    The slow seeds are dropped only when another is near."""
    from handeye.refine.robot_model import _joints
    from handeye.sim.corners import make_corner_session

    s = make_corner_session(mode="eye_in_hand", n_views=20, seed=3, robot_error="kinematic", arm="rm65")
    arm = load_arm("rm65")
    views = [type("View", (), {"view_id": v, "joint_angles": None})() for v in s.view_ids]
    q, source = _joints(arm, views, s.T_base_end_reported)
    assert source == ("inverse_kinematics",) * 20 and all(arm.within_limits(qk) for qk in q)
    np.testing.assert_allclose(arm.T_base_end(q), s.T_base_end_reported, atol=1e-9)


def test_a_reported_pose_the_arm_cannot_reach_keeps_the_joints_before_it_for_the_robot_pose_test():
    """One wrong robot pose (out of the arm's reach) among reachable ones: its view is kept with the previous
    view's joints (the robot-pose test then excludes it), not a refusal of the session; most views out of reach
    mean the table is not the arm's: one line naming the first."""
    from handeye.errors import InputError
    from handeye.refine.robot_model import _joints

    arm = load_arm("rm65")
    q = arm.home_rad + np.radians([[0, 0, 0, 0, 0, 0], [10, -5, 8, 0, 6, 4], [-8, 6, -4, 10, -6, 3]])
    T = arm.T_base_end(q)
    far = T[1].copy()
    far[:3, 3] = [3.0, 0.0, 0.5]  # 3 m away: no arm of this size reaches it
    views = [type("View", (), {"view_id": v, "joint_angles": None})() for v in "123"]
    got, source = _joints(arm, views, np.stack([T[0], far, T[2]]))
    assert source == ("inverse_kinematics", "unreachable", "inverse_kinematics")
    np.testing.assert_allclose(got[1], got[0])
    np.testing.assert_allclose(arm.T_base_end(got[[0, 2]]), T[[0, 2]], atol=1e-9)
    with pytest.raises(InputError, match=r"view 2: the .* cannot reach the reported pose \(2 of 3 views\)"):
        _joints(arm, views, np.stack([T[0], far, far]))


@pytest.mark.parametrize("name", PRESETS)
def test_inverse_kinematics_picks_the_configuration_nearest_the_home(name):
    """A pose about the arm's home has several configurations, each with its own Jacobians: ``nearest`` picks
    the arm's, for a pose of any of them."""
    arm = load_arm(name)
    assert arm.home_rad is not None and arm.within_limits(arm.home_rad)
    q = arm.home_rad + np.radians([10.0, -12.0, 15.0, -8.0, 11.0, 20.0])
    T = arm.T_base_end(q)
    sol = solve_ik(arm, T, seeds=default_ik_seeds(arm, T), nearest=arm.home_rad)
    np.testing.assert_allclose(sol, q, atol=1e-7)
    # another configuration of the same pose is found from a seed near it
    far = solve_ik(arm, T, seeds=default_ik_seeds(arm, T), nearest=-arm.home_rad)
    np.testing.assert_allclose(arm.T_base_end(far), T, atol=1e-9)
    assert np.abs(far - q).max() > 0.5


def test_a_dh_table_states_its_home_in_its_angle_unit():
    table = {
        "name": "two",
        "convention": "standard",
        "angle_unit": "deg",
        "links": [{"a": 0.3, "alpha": 0, "d": 0, "theta_offset": 0}, {"a": 0.2, "alpha": 0, "d": 0, "theta_offset": 0}],
    }
    assert chain_from_dict(table).home_rad is None
    arm = chain_from_dict(table | {"home": [90, -45]})
    np.testing.assert_allclose(arm.home_rad, np.radians([90, -45]))
    assert chain_from_dict(chain_to_dict(arm)).home_rad == pytest.approx(arm.home_rad)
    with pytest.raises(ConfigError, match="invalid home of the DH table"):
        chain_from_dict(table | {"home": [90]}, source="two.yaml")


def test_stacked_joint_angles_give_stacked_poses():
    arm = load_arm("ur5e")
    q = np.random.default_rng(1).uniform(-1, 1, (4, 6))
    T = arm.T_base_end(q)
    assert T.shape == (4, 4, 4)
    np.testing.assert_allclose(T[2], arm.T_base_end(q[2]), atol=0)


def test_bad_tables_are_refused_with_the_field_named():
    good = {"name": "x", "convention": "standard", "links": [{"a": 0, "alpha": 0, "d": 0.1, "theta_offset": 0}]}
    assert chain_from_dict(good).n_joints == 1
    with pytest.raises(ConfigError, match="convention"):
        chain_from_dict(dict(good, convention="craig"))
    with pytest.raises(ConfigError, match="lacks alpha"):
        chain_from_dict(dict(good, links=[{"a": 0, "d": 0, "theta_offset": 0}]))
    with pytest.raises(ConfigError, match="unit"):
        chain_from_dict(dict(good, length_unit="inch"))
    with pytest.raises(ConfigError, match="unknown robot model"):
        load_arm("no_such_arm")
    with pytest.raises(ConfigError, match="joint limits"):
        DHChain("x", "standard", np.zeros((1, 4)), joint_limits_rad=np.array([[1.0, -1.0]]))
    with pytest.raises(ValueError, match="6 joint angles"):
        load_arm("rm65").T_base_end(np.zeros(5))


# the JSON form other tools write (here: Universal Robots' UR3e table as the UR3 data set's author stated it)
UR3E_JSON = {
    "robot_name": "UR3e",
    "dh_convention": "standard",
    "degrees_of_freedom": 6,
    "units": {"length": "m", "angle": "rad"},
    "joints": [
        {"joint_id": f"J{i + 1}", "a": a, "alpha": al, "d": d, "theta_offset": 0.0}
        for i, (a, al, d) in enumerate(
            [
                (0.0, np.pi / 2, 0.15185),
                (-0.24355, 0.0, 0.0),
                (-0.2132, 0.0, 0.0),
                (0.0, np.pi / 2, 0.13105),
                (0.0, -np.pi / 2, 0.08535),
                (0.0, 0.0, 0.0921),
            ]
        )
    ],
}


def test_a_json_table_with_a_units_block_reads_as_the_same_table_in_mm_and_deg(tmp_path):
    import json

    (tmp_path / "ur3e.json").write_text(json.dumps(UR3E_JSON))
    arm = load_arm("ur3e.json", folder=tmp_path)  # relative to the folder, as a session's robot: is
    assert arm.name == "UR3e" and arm.convention == "standard" and arm.n_joints == 6
    mm_deg = dict(
        UR3E_JSON,
        units={"length": "millimetres", "angle": "degrees"},
        joints=[dict(j, a=1e3 * j["a"], d=1e3 * j["d"], alpha=np.degrees(j["alpha"])) for j in UR3E_JSON["joints"]],
    )
    np.testing.assert_allclose(chain_from_dict(mm_deg).dh, arm.dh, atol=1e-12)
    # the UR3e at zero joint angles lies along -x like the UR5e: flange at (a2 + a3, -(d4 + d6), d1 - d5)
    np.testing.assert_allclose(arm.T_base_end(np.zeros(6))[:3, 3], [-0.45675, -0.22315, 0.0665], atol=1e-9)


def test_unreadable_json_tables_are_one_config_error_naming_the_file(tmp_path):
    import json

    bad = tmp_path / "arm.json"
    bad.write_text('{"dh_convention": "standard", "joints": [1, ]}')
    with pytest.raises(ConfigError, match="cannot read the DH table") as e:
        load_arm(bad)
    assert e.value.path == str(bad) and e.value.line == 1 and "JSONDecodeError" in str(e.value)
    for change, match in (
        (dict(units={"length": "inch", "angle": "rad"}), "unit"),
        (dict(units="m"), "units must be a mapping"),
        (dict(degrees_of_freedom=7), "degrees_of_freedom"),
        (dict(links=UR3E_JSON["joints"]), "both links and joints"),
        (dict(length_unit="m"), "units twice"),
        (dict(name="x"), "both name and robot_name"),
    ):
        bad.write_text(json.dumps(dict(UR3E_JSON, **change)))
        with pytest.raises(ConfigError, match=match):
            load_arm(bad)
    with pytest.raises(ConfigError, match="unknown robot model"):
        load_arm(tmp_path / "missing.json")
    bad_yaml = tmp_path / "arm.yaml"
    bad_yaml.write_text("name: x\nlinks: [{a: 0\n")
    with pytest.raises(ConfigError, match="cannot read the DH table") as e:
        load_arm(bad_yaml)
    assert e.value.line is not None and "expected a YAML file" in str(e.value)


# Universal Robots' published DH tables (d1, a2, a3, d4, d5, d6 in m; alpha = 90, 0, 0, 90, -90, 0 deg)
UR_TABLES = {
    "ur3": (0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
    "ur3e": (0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
    "ur5": (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    "ur5e": (0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
    "ur10": (0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922),
    "ur10e": (0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655),
    "ur16e": (0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655),
}


@pytest.mark.parametrize("name", sorted(UR_TABLES))
def test_universal_robots_presets_are_the_published_tables(name):
    assert name in PRESETS
    d1, a2, a3, d4, d5, d6 = UR_TABLES[name]
    arm = load_arm(name)
    assert arm.convention == "standard" and arm.n_joints == 6
    np.testing.assert_allclose(arm.dh[:, 0], [0, a2, a3, 0, 0, 0], atol=1e-12)  # a
    np.testing.assert_allclose(np.degrees(arm.dh[:, 1]), [90, 0, 0, 90, -90, 0], atol=1e-12)  # alpha
    np.testing.assert_allclose(arm.dh[:, 2], [d1, 0, 0, d4, d5, d6], atol=1e-12)  # d
    np.testing.assert_allclose(arm.dh[:, 3], 0, atol=0)  # theta offsets
    T = arm.T_base_end(np.zeros(6))  # stretched along -x, the flange's z axis along -y
    np.testing.assert_allclose(T[:3, 3], [a2 + a3, -(d4 + d6), d1 - d5], atol=1e-12)
    np.testing.assert_allclose(T[:3, 2], [0.0, -1.0, 0.0], atol=1e-12)
    assert arm.error_prior is not None


def test_every_table_in_configs_robots_is_a_preset_of_the_installed_package():
    from pathlib import Path

    folder = Path(__file__).resolve().parents[1] / "configs" / "robots"
    assert PRESETS == ("rm65", "ur10", "ur10e", "ur16e", "ur3", "ur3e", "ur5", "ur5e")  # read from the package data
    assert set(PRESETS) == {f.stem for f in folder.glob("*.yaml")}  # the checkout ships the same tables


def test_the_ur3e_preset_gives_the_ur3_sets_flange_poses(shared_dataset):
    """The UR3 set's arm is a UR3e: the preset's forward kinematics of its recorded joint angles are the flange
    poses its SOURCE.md derives with the set's own nominal table."""
    import json

    folder = shared_dataset("ur3-eyetohand-cam1")
    own = load_arm(folder / "robot_model_dh_nominal_ur3a.json")
    np.testing.assert_allclose(load_arm("ur3e").dh, own.dh, atol=1e-9)
    poses = json.loads((folder / "dataset_ur3a_joint_images_40poses.json").read_text())["poses"]
    derived = {
        int(r.split()[0]): np.array(r.split()[2:], float).reshape(4, 4)
        for r in (folder / "base_T_flange_fk_derived.txt").read_text().splitlines()
        if r and not r.startswith("#")
    }
    assert len(derived) == len(poses) == 40
    for p in poses:
        q = np.radians([p["joint_angles_deg"][f"joint_{j}"] for j in range(1, 7)])
        np.testing.assert_allclose(load_arm("ur3e").T_base_end(q), derived[p["pose_id"]], atol=1e-8)
