"""The initial estimate (handeye.initial): intrinsics, board poses with the symmetric-board ordering,
motion quality, OpenCV's closed forms in both modes; and the observation stage of the pipeline.

Ground truth at two levels (STYLE 12): noiseless corners recover the truth to ~1e-8; noisy corners
give errors that scale with the pixel noise."""

import cv2
import numpy as np
import pytest

from handeye.camera import pixels_from_board_points
from handeye.config import load_preset
from handeye.errors import DetectionError
from handeye.frames import T_from_rotvec, inv_T, pose_error
from handeye.initial import (
    METHODS,
    board_poses,
    calibrate_intrinsics,
    chain_residuals,
    consistency,
    motion_quality,
    reprojection_rms,
    rotations_to_add,
    solve_closed_form,
    solve_pnp,
)
from handeye.initial.motion import default_thresholds
from handeye.mounting import mounting
from handeye.pipeline import CalibrateOptions, observe
from handeye.records import Detection
from handeye.sim.corners import make_corner_session
from handeye.targets import ChessboardSpec


def closed_form_inputs(cs, *, detections=None, target=None):
    mode = mounting(cs.mode)
    dets = list(detections or cs.detections())
    M = {d.view_id: mode.M_from_T_base_end(cs.T_base_end_reported[cs.index(d.view_id)]) for d in dets}
    poses = board_poses(dets, target or cs.target, cs.intrinsics, M)
    ids = [d.view_id for d in dets]
    return mode, np.stack([poses[v].T_cam_board for v in ids]), np.stack([M[v] for v in ids]), poses


# ------------------------------------------------------------------------------ closed forms
@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
@pytest.mark.parametrize("method", METHODS)
def test_noiseless_corners_recover_the_truth_with_every_method(mode, method):
    cs = make_corner_session(mode=mode, n_views=12, seed=3, noise_px=0.0)
    m, C, M, _ = closed_form_inputs(cs)
    est = solve_closed_form(m, C, M, method=method)
    assert est.status == "ok" and est.method == method and est.mode == mode
    r, t = pose_error(est.T_x, cs.T_x_true)
    rb, tb = pose_error(est.T_board, cs.T_board_true)
    assert r < 1e-6 and t < 1e-3, (method, r, t)  # 1e-6 deg and 1e-6 m
    assert rb < 1e-6 and tb < 1e-3, (method, rb, tb)
    # the same solution explains every view: board scatter and residuals through the robot chain ~0
    dt_mm, dr_deg = consistency(est, m, C, M)
    assert dt_mm < 1e-4 and dr_deg < 1e-6


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_noisy_closed_form_error_scales_with_the_pixel_noise(mode):
    def rms_error(noise_px):
        errs = []
        for seed in range(5):
            cs = make_corner_session(mode=mode, n_views=20, seed=seed, noise_px=noise_px)
            m, C, M, _ = closed_form_inputs(cs)
            errs.append(pose_error(solve_closed_form(m, C, M, method="park").T_x, cs.T_x_true))
        return np.sqrt(np.mean(np.square(errs), axis=0))

    lo, hi = rms_error(0.1), rms_error(0.3)
    # the same noise draws scaled by 3: an error that comes from the noise triples (to first order);
    # a bias (wrong convention, wrong pairing) would not
    np.testing.assert_allclose(hi / lo, 3.0, rtol=0.1)
    # per pixel of noise, 20 views: measured 0.075-0.105 deg/px and 1.2-1.45 mm/px
    assert hi[0] < 0.15 * 0.3 and hi[1] < 2.0 * 0.3, hi


def test_eye_to_hand_data_is_not_solved_by_the_eye_in_hand_model():
    cs = make_corner_session(mode="eye_to_hand", n_views=12, seed=1, noise_px=0.0)
    _, C, _, _ = closed_form_inputs(cs)
    wrong = mounting("eye_in_hand")
    est = solve_closed_form(wrong, C, wrong.M_from_T_base_end(cs.T_base_end_reported), method="tsai")
    assert est.status == "failed" or pose_error(est.T_x, cs.T_x_true)[1] > 50
    if est.status == "ok":  # the wrong model shows in the board scatter (the right one: < 1e-4 mm)
        assert consistency(est, wrong, C, wrong.M_from_T_base_end(cs.T_base_end_reported))[0] > 10


def test_unknown_method_is_named():
    cs = make_corner_session(mode="eye_in_hand", n_views=4, seed=0, noise_px=0.0)
    m, C, M, _ = closed_form_inputs(cs)
    with pytest.raises(Exception) as e:
        solve_closed_form(m, C, M, method="nope")
    assert e.value.code == "unknown_method" and "tsai | park" in str(e.value)


def test_chain_residuals_are_zero_for_the_truth_and_grow_with_a_wrong_pose():
    cs = make_corner_session(mode="eye_in_hand", n_views=6, seed=4, noise_px=0.0)
    m, C, M, poses = closed_form_inputs(cs)
    est = solve_closed_form(m, C, M, method="park")
    dets = {d.view_id: d for d in cs.detections()}
    T_base_end = {v: cs.T_base_end_reported[cs.index(v)] for v in dets}
    res = chain_residuals(est, m, cs.target.object_points(), poses, dets, T_base_end, cs.intrinsics)
    assert max(mx for _, mx in res.values()) < 1e-5
    T_base_end["3"] = T_base_end["3"] @ T_from_rotvec([0, 0, 0], [0.005, 0, 0])  # 5 mm off
    res = chain_residuals(est, m, cs.target.object_points(), poses, dets, T_base_end, cs.intrinsics)
    assert res["3"][1] > 3.0 and max(mx for v, (_, mx) in res.items() if v != "3") < 1e-5


# ------------------------------------------------------------------------------ board poses
def test_board_pose_and_its_rms_use_the_one_projection_which_matches_opencv():
    cs = make_corner_session(mode="eye_in_hand", n_views=3, seed=6, noise_px=0.0)
    d = cs.detections()[0]
    obj = cs.target.object_points()[d.corner_ids]
    T, rms = solve_pnp(obj, d.image_points, cs.intrinsics)
    assert rms < 1e-6 and pose_error(T, cs.T_cam_board_true[0])[1] < 1e-6
    # cv2.projectPoints as the oracle of handeye.camera's projection (distortion included)
    px = cv2.projectPoints(
        obj.reshape(-1, 1, 3), cv2.Rodrigues(T[:3, :3])[0], T[:3, 3], cs.intrinsics.K, cs.intrinsics.dist_array
    )[0].reshape(-1, 2)
    np.testing.assert_allclose(pixels_from_board_points(T, obj, cs.intrinsics), px, atol=1e-9)
    shifted = d.image_points + np.array([0.3, -0.4])  # 0.5 px everywhere
    assert abs(reprojection_rms(obj, shifted, T, cs.intrinsics) - 0.5) < 1e-9


def test_symmetric_board_turned_views_give_the_same_result():
    sym = ChessboardSpec(9, 7, 0.03)  # 10 x 8 squares: 180-degree symmetric colour pattern
    cs = make_corner_session(mode="eye_in_hand", n_views=14, seed=5, noise_px=0.2, target=sym)
    m, C_ref, M, _ = closed_form_inputs(cs)
    ref = solve_closed_form(m, C_ref, M, method="tsai")
    # a detector reports some views in the 180-degree turned order: corner k is really id n-1-k
    flipped = [
        Detection(d.view_id, d.corner_ids, d.image_points[::-1].copy(), d.image_size) if k % 3 == 1 else d
        for k, d in enumerate(cs.detections())
    ]
    m, C, M, poses = closed_form_inputs(cs, detections=flipped, target=sym)
    assert [poses[d.view_id].orientation for d in flipped] == [int(k % 3 == 1) for k in range(len(flipped))]
    est = solve_closed_form(m, C, M, method="tsai")
    r, t = pose_error(est.T_x, ref.T_x)
    assert r < 1e-6 and t < 1e-3, (r, t)  # the same corners in the same frame: the same solution


def test_square_board_resolves_quarter_turns():
    sq = ChessboardSpec(7, 7, 0.03)
    cs = make_corner_session(mode="eye_to_hand", n_views=12, seed=2, noise_px=0.1, target=sq)
    m, C_ref, M_ref, _ = closed_form_inputs(cs)
    ref = solve_closed_form(m, C_ref, M_ref, method="park")
    perms = sq.symmetries()
    assert len(perms) == 4
    dets = []
    for k, d in enumerate(cs.detections()):
        inv = np.argsort(perms[k % 4])  # detected index j holds the corner whose true id is perms[k % 4][j]
        dets.append(Detection(d.view_id, d.corner_ids, d.image_points[inv].copy(), d.image_size))
    m, C, M, poses = closed_form_inputs(cs, detections=dets, target=sq)
    assert len({poses[d.view_id].orientation for d in dets}) == 4
    est = solve_closed_form(m, C, M, method="park")
    r, t = pose_error(est.T_x, ref.T_x)
    assert r < 1e-6 and t < 1e-3, (r, t)  # every turn undone: the untouched views' solution


def test_every_ordering_is_kept_so_another_reading_of_the_poses_can_choose_its_own():
    from handeye.initial.board_poses import candidate_invariants, orientation_labels

    sym = ChessboardSpec(7, 5, 0.03)  # odd x odd: 180-degree symmetric
    cs = make_corner_session(mode="eye_in_hand", n_views=12, seed=6, noise_px=0.1, target=sym)
    flipped = [
        Detection(d.view_id, d.corner_ids, d.image_points[::-1].copy(), d.image_size) if k % 3 == 1 else d
        for k, d in enumerate(cs.detections())
    ]
    m, C, M, poses = closed_form_inputs(cs, detections=flipped, target=sym)
    ids = [d.view_id for d in flipped]
    Cs = np.stack([np.stack(poses[v].candidates) for v in ids])  # (n, 2, 4, 4)
    assert Cs.shape == (12, 2, 4, 4)
    for v in ids:  # the chosen ordering's pose is the candidate of that index
        np.testing.assert_allclose(poses[v].candidates[poses[v].orientation], poses[v].T_cam_board)
    lab = orientation_labels(candidate_invariants(Cs), M)
    assert list(lab) == [int(k % 3 == 1) for k in range(12)]  # the detector's order kept for the majority
    # an asymmetric board keeps no candidates
    m, C, M, poses = closed_form_inputs(make_corner_session(mode="eye_in_hand", n_views=5, seed=6, noise_px=0.1))
    assert all(p.candidates == () for p in poses.values())


def _icm_every_start(cost: np.ndarray) -> np.ndarray:
    """orientation_labels' search written plainly: every start, three full rounds, costs summed afresh."""
    n, k = cost.shape[:2]
    idx = np.arange(n)
    best, best_cost = None, np.inf
    for r in range(n):
        lab = np.argmin(cost[:, :, r, 0], axis=1)
        lab[r] = 0
        for _ in range(3):
            for i in range(n):
                lab[i] = int(np.argmin(cost[i][:, idx, lab].sum(axis=1)))
        c = cost[idx[:, None], lab[:, None], idx[None, :], lab[None, :]].sum()
        if c < best_cost:
            best, best_cost = lab.copy(), c
    return best


def test_the_labelling_search_is_the_plain_one_to_the_bit():
    """Running the distinct starts side by side, stopping at a round that changes nothing and gathering each
    view's costs as contiguous rows give the labels of the plain search, on noisy and on junk candidates."""
    from handeye.frames import T_from_rotvec, screw_invariants
    from handeye.initial.board_poses import candidate_invariants, orientation_labels

    def pose(rot_sigma: float, trans_sigma: float):
        return T_from_rotvec(rng.normal(size=3) * rot_sigma, rng.normal(size=3) * trans_sigma)

    rng = np.random.default_rng(11)
    for trial in range(40):
        n, k = int(rng.integers(3, 30)), int(rng.choice([2, 4]))
        Ms = np.stack([pose(0.6, 0.2) for _ in range(n)])
        X, B = pose(1.0, 0.2), pose(1.0, 0.2)
        noise = 0.3 if trial % 3 == 0 else 0.02  # a third with candidates far from any consistent labelling
        turns = [T_from_rotvec([0, 0, a * 2 * np.pi / k], [0.01 * a, 0, 0]) for a in range(k)]
        Cs = np.stack([np.stack([X @ M @ B @ turn @ pose(noise, 0.002) for turn in turns]) for M in Ms])
        ang_C, pitch_C = candidate_invariants(Cs)
        rel_M = Ms[:, None] @ np.linalg.inv(Ms)[None, :]
        ang_M, pitch_M = (v.reshape(n, 1, n, 1) for v in screw_invariants(rel_M.reshape(-1, 4, 4)))
        cost = np.abs(ang_C - ang_M) + np.abs(pitch_C - pitch_M) / 0.1
        cost[np.arange(n), :, np.arange(n), :] = 0.0
        assert np.array_equal(orientation_labels((ang_C, pitch_C), Ms, turns=False), _icm_every_start(cost))


# ------------------------------------------------------------------------------ intrinsics
def test_intrinsics_from_noiseless_corners_and_too_few_views():
    cs = make_corner_session(mode="eye_in_hand", n_views=10, seed=8, noise_px=0.0)
    dets = list(cs.detections())
    intr, rms = calibrate_intrinsics(dets, cs.target.object_points())
    assert rms < 1e-4
    np.testing.assert_allclose(intr.as_vector()[:4], cs.intrinsics.as_vector()[:4], atol=1e-4)  # pixels
    np.testing.assert_allclose(intr.as_vector()[[4, 6, 7]], cs.intrinsics.as_vector()[[4, 6, 7]], atol=1e-5)  # k1 p1 p2
    # k2 and k3 trade against each other inside the board's radius: compare the pixels they make
    obj = cs.target.object_points()
    for T in cs.T_cam_board_true:
        d_px = pixels_from_board_points(T, obj, intr) - pixels_from_board_points(T, obj, cs.intrinsics)
        assert np.abs(d_px).max() < 1e-3
    with pytest.raises(DetectionError) as e:
        calibrate_intrinsics(dets[:2], cs.target.object_points())
    assert e.value.code == "target_not_found" and e.value.exit_code == 3


# ------------------------------------------------------------------------------ motion quality
def test_motion_thresholds_come_from_the_calibration_preset():
    m = load_preset("calibration")["motion"]
    t = default_thresholds()
    assert (t.min_rotation_deg, t.min_axis_spread_deg) == (m["min_rotation_deg"], m["min_axis_spread_deg"])
    assert (t.min_rotation_deg, t.min_axis_spread_deg) == (10.0, 5.0)
    M = np.stack([T_from_rotvec(np.radians([0, 0, a]), [0, 0, 0]) for a in (0, 4, 8)])  # 8 deg about z only
    mq = motion_quality(M, frame="end")
    assert mq.code == "motion_small_rotation" and abs(mq.max_rotation_deg - 8.0) < 1e-9
    assert mq.min_rotation_deg == 10.0 and "needs 10" in mq.reason
    assert motion_quality(M, frame="end", min_rotation_deg=5.0).code == "motion_one_axis"  # the next gate


def test_degenerate_motion_names_the_axis_and_what_to_add():
    rng = np.random.default_rng(0)
    M = np.stack([T_from_rotvec([0, 0, a], rng.normal(0, 0.1, 3)) for a in np.linspace(-1, 1, 10)])
    mq = motion_quality(M, frame="end")
    assert mq.status == "degenerate" and mq.code == "motion_one_axis"
    assert "[+0.00, +0.00, +1.00]" in mq.reason and mq.axis_spread_deg < 1e-6
    np.testing.assert_allclose(np.abs(mq.main_axis), [0, 0, 1], atol=1e-9)
    assert rotations_to_add(M, "end") == "the end x axis and the end y axis (across the end z axis, the only one used)"
    # rotations about x and z: y is what is missing
    M2 = np.stack([T_from_rotvec(np.radians([a, 0, b]), [0, 0, 0]) for a, b in ((0, 0), (30, 0), (0, 30), (20, 20))])
    assert motion_quality(M2, frame="base").status == "ok"
    assert rotations_to_add(M2, "base").startswith("the base y axis")
    cs = make_corner_session(mode="eye_in_hand", n_views=10, seed=0, noise_px=0.0)
    good = motion_quality(inv_T(cs.T_base_end_reported), frame="end")
    assert good.status == "ok" and good.code == "" and good.max_rotation_deg > 20


def test_too_few_views_is_degenerate():
    mq = motion_quality(np.stack([np.eye(4)] * 2), frame="end")
    assert mq.status == "degenerate" and mq.code == "too_few_views" and mq.n_views == 2


# ------------------------------------------------------------------------------ the observation stage
def test_observe_with_given_intrinsics_of_another_size_stops_with_its_code(tmp_path):
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session

    s = write_vendor_session(
        tmp_path / "s",
        mode="eye_in_hand",
        n_views=4,
        seed=1,
        hidden_views=("2",),
        intrinsics=default_intrinsics(640, 480),
        supersample=2,
    )
    items = [(str(k), s / f"{k}.jpg") for k in range(1, 5)]
    obs = observe(target=_session_target(s), items=items, options=CalibrateOptions())
    assert obs.error is None and sorted(obs.detections) == ["1", "3", "4"] and list(obs.failures) == ["2"]
    assert not obs.outcomes["2"].used and "not found" in obs.outcomes["2"].reason
    assert obs.intrinsics is not None and obs.intrinsics_rms_px < 0.2
    assert all(bp.rms_px < 0.2 for bp in obs.board_poses.values())
    other = default_intrinsics(1280, 720)
    obs2 = observe(target=_session_target(s), items=items, intrinsics=other, options=CalibrateOptions())
    assert obs2.error.code == "intrinsics_size_mismatch" and "1280x720" in str(obs2.error) and not obs2.board_poses
    obs3 = observe(target=_session_target(s), items=items[:2], options=CalibrateOptions())
    assert obs3.error.code == "target_not_found" and obs3.intrinsics is None


def _session_target(path):
    from handeye.session import load_session

    return load_session(path).target


def test_all_methods_on_threads_equal_each_method_alone(monkeypatch):
    """The methods solved side by side give each method's own solution, in METHODS' order; one that raises
    is recorded as failed without stopping the others (with one core or several)."""
    from handeye.initial import closed_form
    from handeye.initial.closed_form import METHODS, all_methods, solve_closed_form

    cs = make_corner_session(mode="eye_in_hand", n_views=12, seed=2, robot_noise=(0.3, 0.05), noise_px=0.3)
    mode = mounting("eye_in_hand")
    C = np.asarray(cs.T_cam_board_true)
    M = mode.M_from_T_base_end(np.asarray(cs.T_base_end_reported))
    real = closed_form.solve_closed_form

    def park_raises(mode_, C_, M_, *, method="tsai"):
        if method == "park":
            raise cv2.error("park: no solution")
        return real(mode_, C_, M_, method=method)

    monkeypatch.setattr(closed_form, "solve_closed_form", park_raises)
    for cores in (2, 1):
        monkeypatch.setattr(closed_form, "usable_cores", lambda c=cores: c)
        got = all_methods(mode, C, M)
        assert list(got) == list(METHODS)
        assert got["park"].status == "failed" and "no solution" in got["park"].failure_reason
        for m in METHODS:
            if m != "park":
                alone = solve_closed_form(mode, C, M, method=m)
                assert got[m].status == "ok" and np.array_equal(got[m].T_x, alone.T_x), m
                assert np.array_equal(got[m].T_board, alone.T_board), m
