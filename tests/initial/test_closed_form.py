"""The closed forms' cost bound (handeye.initial.closed_form): OpenCV's hand-eye methods, which use every
pair of the views they get, see at most MAX_PAIRED_VIEWS views spread over the robot rotations, and still
recover the truth from noiseless data; small sessions give them every view."""

import numpy as np
import pytest

from handeye.frames import T_from_rotvec, pose_error
from handeye.initial import closed_form as cf
from handeye.initial.closed_form import HAND_EYE_METHODS, MAX_PAIRED_VIEWS, METHODS, solve_closed_form, spread_views
from handeye.mounting import mounting


def _exact(n: int, seed: int = 5):
    """Noiseless ``C_i = A M_i B`` for ``n`` random robot motions: (mode, C, M, X, B)."""
    rng = np.random.default_rng(seed)
    mode = mounting("eye_in_hand")
    T_base_end = np.stack(
        [T_from_rotvec(rng.uniform(-0.6, 0.6, 3), rng.uniform(-0.2, 0.2, 3) + [0.4, 0.0, 0.5]) for _ in range(n)]
    )
    X = T_from_rotvec([0.1, -0.2, 0.3], [0.02, 0.05, 0.08])  # T_end_cam
    B = T_from_rotvec([3.0, 0.1, -0.2], [0.5, 0.1, 0.0])  # T_base_board
    M = mode.M_from_T_base_end(T_base_end)
    C = mode.predict_T_cam_board(X, B, T_base_end)
    return mode, C, M, X, B


def test_spread_views_keeps_every_view_up_to_k_and_is_deterministic():
    _, _, M, _, _ = _exact(150)
    assert np.array_equal(spread_views(M[:40], 60), np.arange(40))
    a, b = spread_views(M, 60), spread_views(M, 60)
    assert np.array_equal(a, b) and len(a) == 60 and len(np.unique(a)) == 60
    assert np.all(np.diff(a) > 0) and a[0] == 0  # sorted, from the first view on


def test_spread_views_choose_the_varied_rotations():
    """90 views at nearly one orientation and 10 far apart: 11 spread views take all 10 and one of the 90."""
    rng = np.random.default_rng(2)
    near = [T_from_rotvec(rng.normal(0, 0.002, 3), [0, 0, 0]) for _ in range(90)]
    far = [
        T_from_rotvec(v, [0, 0, 0])
        for v in 0.8 * np.vstack([np.eye(3), -np.eye(3), [[0.6, 0.6, 0], [0, 0.6, 0.6], [0.6, 0, 0.6], [-0.6, 0.6, 0]]])
    ]
    M = np.stack(near[:45] + far + near[45:])
    got = spread_views(M, 11)
    assert set(range(45, 55)) <= set(got.tolist()) and len(got) == 11


@pytest.mark.parametrize("method", METHODS)
def test_a_large_session_is_solved_exactly_with_every_method(method):
    """150 noiseless views (above MAX_PAIRED_VIEWS): every method still recovers X and the board to ~1e-8."""
    mode, C, M, X, B = _exact(150)
    assert len(C) > MAX_PAIRED_VIEWS
    est = solve_closed_form(mode, C, M, method=method)
    assert est.status == "ok", est.failure_reason
    r, t = pose_error(est.T_x, X)
    rb, tb = pose_error(est.T_board, B)
    assert r < 1e-6 and t < 1e-3 and rb < 1e-6 and tb < 1e-3, (method, r, t, rb, tb)  # deg, mm


def test_the_hand_eye_methods_see_only_the_spread_views(monkeypatch):
    """OpenCV gets MAX_PAIRED_VIEWS views (its cost is quadratic in them); the robot-world methods get all."""
    mode, C, M, _, _ = _exact(150)
    seen = {}
    real_he, real_rw = cf.cv2.calibrateHandEye, cf.cv2.calibrateRobotWorldHandEye

    def he(*a, **kw):
        seen["hand_eye"] = len(a[0])
        return real_he(*a, **kw)

    def rw(*a, **kw):
        seen["robot_world"] = len(a[0])
        return real_rw(*a, **kw)

    monkeypatch.setattr(cf.cv2, "calibrateHandEye", he)
    monkeypatch.setattr(cf.cv2, "calibrateRobotWorldHandEye", rw)
    solve_closed_form(mode, C, M, method=next(iter(HAND_EYE_METHODS)))
    solve_closed_form(mode, C, M, method="li")
    assert seen == {"hand_eye": MAX_PAIRED_VIEWS, "robot_world": 150}
    solve_closed_form(mode, C[:30], M[:30], method="tsai")
    assert seen["hand_eye"] == 30  # a small session: every view, as before
