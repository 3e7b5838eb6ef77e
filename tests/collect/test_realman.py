"""RealMan JSON client against a local emulator of the controller's TCP port (127.0.0.1, ephemeral)."""

from __future__ import annotations

import json
import socket

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from handeye.collect.realman import (
    JsonStreamDecoder,
    RealmanArm,
    T_base_end_from_realman_pose,
    parse_robot_address,
    realman_error_codes,
    realman_pose_from_T,
)
from handeye.errors import ConfigError, HardwareError
from handeye.frames import make_T, pose_error
from handeye.sim.realman_emulator import RealmanEmulator


# ------------------------------------------------------------------------------ framing
def test_decoder_joins_partial_messages():
    dec = JsonStreamDecoder()
    data = b'{"state":"current_arm_state","arm_state":{"pose":[1,2,3,4,5,6],"err":0}}\r\n'
    out = []
    for i in range(len(data)):  # one byte at a time
        out += dec.feed(data[i : i + 1])
    assert out == [json.loads(data)]
    assert dec.discarded_bytes == 0


def test_decoder_splits_several_objects_in_one_packet():
    dec = JsonStreamDecoder()
    out = dec.feed(b'{"a":1}\r\n{"b":{"c":"}{"}}{"d":[1,{"e":2}]}\r\n{"f"')
    assert out == [{"a": 1}, {"b": {"c": "}{"}}, {"d": [1, {"e": 2}]}]
    assert dec.feed(b":3}\r\n") == [{"f": 3}]


def test_decoder_skips_garbage_and_truncated_objects():
    dec = JsonStreamDecoder()
    out = dec.feed(b'\x00\xffnoise}]{"cut":tr\r\n{"ok":true}\r\n{bad json}\r\n"str"{"x":"esc\\"}"}\r\n')
    assert out == [{"ok": True}, {"x": 'esc"}'}]
    assert dec.discarded_bytes > 0


def test_decoder_bounds_its_buffer():
    dec = JsonStreamDecoder(max_buffer_bytes=100)
    assert dec.feed(b'{"never":"' + b"x" * 200) == []
    assert dec.feed(b'\r\n{"a":1}\r\n') == [{"a": 1}]


# ------------------------------------------------------------------------------ wire conversions
def test_pose_units_and_euler_convention():
    # x 0.1 m, y 0.2 m, z 0.03 m, rx 0.4, ry 0.5, rz 0.6 rad (the vendor's documented example)
    T = T_base_end_from_realman_pose([100000, 200000, 30000, 400, 500, 600])
    np.testing.assert_allclose(T[:3, 3], [0.1, 0.2, 0.03], atol=1e-12)
    R = (
        Rotation.from_rotvec([0, 0, 0.6]) * Rotation.from_rotvec([0, 0.5, 0]) * Rotation.from_rotvec([0.4, 0, 0])
    ).as_matrix()  # R = Rz @ Ry @ Rx
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-12)
    assert realman_pose_from_T(T) == [100000, 200000, 30000, 400, 500, 600]


def test_pose_conversion_rejects_wrong_counts():
    with pytest.raises(ValueError):
        T_base_end_from_realman_pose([1, 2, 3])


@pytest.mark.parametrize(
    "err, codes",
    [
        (0, []),
        ([0], []),
        ([0x1003, 0], [0x1003]),
        ({"err_len": 1, "err": [4109]}, [4109]),
        (None, []),
        ("0x100D", None),
    ],
)
def test_error_code_shapes(err, codes):
    if codes is None:
        with pytest.raises(ValueError):
            realman_error_codes(err)
    else:
        assert realman_error_codes(err) == codes


def test_address_is_required_and_parsed():
    assert parse_robot_address("192.168.1.18") == ("192.168.1.18", 8080)
    assert parse_robot_address("10.0.0.2:9000") == ("10.0.0.2", 9000)
    assert parse_robot_address("[::1]:8081") == ("::1", 8081)
    for bad in ("", "host:99999", ":8080"):
        with pytest.raises(ConfigError):
            parse_robot_address(bad)


# ------------------------------------------------------------------------------ against the emulator
def _arm(emu, **kw):
    return RealmanArm(*emu.address, timeout_s=kw.pop("timeout_s", 0.5), **kw)


def test_connect_sets_base_work_frame_and_reads_pose():
    T = make_T(Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix(), [0.31, -0.12, 0.42])
    with RealmanEmulator(T_base_end=T) as emu:
        arm = _arm(emu)
        reading = arm.read_pose()
        arm.close()
    assert emu.work_frame == "Base"
    assert emu.received[0] == {"command": "set_change_work_frame", "frame_name": "Base"}
    rot_deg, trans_mm = pose_error(reading.T_base_end, T)
    assert trans_mm < 1e-3 and rot_deg < 0.06  # quantised to 0.001 mm and 0.001 rad on the wire
    assert reading.errors == [] and reading.state["tool_frame"] == "Arm_Tip"


@pytest.mark.parametrize("fault", ["split", "merge", "garbage", "truncate"])
def test_read_survives_stream_faults(fault):
    with RealmanEmulator() as emu:
        arm = _arm(emu)
        emu.faults.extend([fault, fault])
        a = arm.read_pose()
        b = arm.read_pose()
        arm.close()
    expected = T_base_end_from_realman_pose(emu.pose_units)  # what the controller holds, as sent on the wire
    np.testing.assert_array_equal(a.T_base_end, expected)
    np.testing.assert_array_equal(b.T_base_end, expected)
    assert emu.connections == 1  # no reconnect was needed


@pytest.mark.parametrize("fault", ["drop", "silent", "malformed"])
def test_read_is_retried_on_a_fresh_connection(fault):
    with RealmanEmulator() as emu:
        arm = _arm(emu, timeout_s=0.3)
        emu.faults.append(fault)
        reading = arm.read_pose()
        arm.close()
    assert reading.T_base_end.shape == (4, 4)
    assert emu.connections == 2


def test_read_gives_up_with_one_line_error():
    with RealmanEmulator() as emu:
        arm = _arm(emu, timeout_s=0.2, read_retries=1)
        emu.faults.extend(["drop"] * 6)
        with pytest.raises(HardwareError) as ei:
            arm.read_pose()
        arm.close()
    assert "did not answer 'get_current_arm_state'" in str(ei.value) and "\n" not in str(ei.value)


def test_unreachable_arm_is_a_hardware_error():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens on this port now
    with pytest.raises(HardwareError, match="cannot reach the RealMan arm"):
        RealmanArm("127.0.0.1", port, timeout_s=0.3)


@pytest.mark.parametrize("err_format", ["list", "int", "dict"])
def test_error_codes_are_reported_and_block_motion(err_format):
    with RealmanEmulator(errors=[0x100D], err_format=err_format) as emu:
        arm = _arm(emu)
        assert arm.read_pose().errors == [0x100D]
        with pytest.raises(HardwareError, match="collision"):
            arm.move_to(arm.read_pose().T_base_end, speed_fraction=0.1)
        arm.close()
    assert not any(c["command"] in ("movel", "movej_p") for c in emu.received)


@pytest.mark.parametrize("motion", ["movej_p", "movel"])
def test_motion_completes_and_speed_is_capped(motion):
    with RealmanEmulator() as emu:
        arm = _arm(emu, motion=motion, max_speed_fraction=0.25)
        T = arm.read_pose().T_base_end @ make_T(Rotation.from_rotvec([0.1, 0, 0]).as_matrix(), [0.01, 0, 0])
        arm.move_to(T, speed_fraction=0.9)
        after = arm.read_pose().T_base_end
        arm.close()
    cmd = [c for c in emu.received if c["command"] == motion]
    assert len(cmd) == 1 and cmd[0]["v"] == 25 and cmd[0]["r"] == 0
    rot_deg, trans_mm = pose_error(after, T)
    # the target reaches the controller quantised to 0.001 mm and 0.001 rad (as in the read test)
    assert trans_mm < 1e-3 and rot_deg < 0.06


@pytest.mark.parametrize("fault, message", [("refuse", "refused"), ("fail_motion", "failed")])
def test_refused_or_failed_motion_raises(fault, message):
    with RealmanEmulator() as emu:
        arm = _arm(emu, motion="movel")
        T = arm.read_pose().T_base_end
        emu.faults.extend([None, fault])  # None: the pre-motion pose read answers normally
        with pytest.raises(HardwareError, match=message):
            arm.move_to(T, speed_fraction=0.1)
        arm.close()


def test_dropped_connection_during_motion_is_not_resent():
    with RealmanEmulator() as emu:
        arm = _arm(emu)
        T = arm.read_pose().T_base_end
        emu.faults.extend([None, "drop"])  # pose read answers, the motion's acknowledgement is dropped
        with pytest.raises(HardwareError, match="may still be moving"):
            arm.move_to(T, speed_fraction=0.1)
        arm.close()
    assert sum(c["command"] == "movej_p" for c in emu.received) == 1


def test_silent_motion_times_out_and_stops_the_arm():
    with RealmanEmulator() as emu:
        arm = _arm(emu, timeout_s=0.2, motion="movel")
        T = arm.read_pose().T_base_end
        emu.faults.extend([None, "silent"])
        emu.motion_time_s = 0.5  # completion arrives after the acknowledgement timeout
        with pytest.raises(HardwareError, match="stop command confirmed"):
            arm.move_to(T, speed_fraction=0.1)
        arm.close()
    names = [c["command"] for c in emu.received]
    assert names.count("movel") == 1 and "set_arm_stop" in names


def test_emulator_rejects_unknown_fault():
    with pytest.raises(ValueError):
        RealmanEmulator(faults=["explode"])


def test_joint_angles_are_read_in_radians_and_match_the_pose():
    from handeye.kinematics import load_arm

    arm = load_arm("rm65")
    q = np.radians([10.0, -20.0, 70.0, 5.0, 40.0, -30.0])
    with RealmanEmulator(T_base_end=arm.T_base_end(q)) as emu:
        with _arm(emu) as robot:
            r = robot.read_pose()
    assert r.state["joint_mdeg"] and len(r.joints) == 6
    # the controller's 0.001 deg joints and its 0.001 mm pose describe the same flange pose
    rot_deg, trans_mm = pose_error(arm.T_base_end(np.array(r.joints)), r.T_base_end)
    assert trans_mm < 0.01 and rot_deg < 0.001
