"""calibrateCamera's intrinsics are a function of the corners: the same to the bit in every run and interpreter."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from handeye.initial import calibrate_intrinsics
from handeye.sim.corners import make_corner_session

REPO = Path(__file__).resolve().parents[2]

# a small calibration and the verification plan on it: every number the plan's greedy choice rests on
_SCRIPT = """
import numpy as np
from handeye.initial import calibrate_intrinsics, solve_pnp
from handeye.initial.closed_form import all_methods
from handeye.mounting import mounting
from handeye.recal.loaded import load_result, result_from_refinement
from handeye.recal.plan import plan_verification
from handeye.refine import RefineView, refine
from handeye.sim.corners import make_corner_session

s = make_corner_session(mode="eye_in_hand", n_views=10, seed=4, noise_px=0.3, robot_noise=(0.2, 0.05))
obj, dets = s.target.object_points(), s.detections()
intr, _ = calibrate_intrinsics(dets, obj)
m = mounting(s.mode)
C = np.stack([solve_pnp(obj[d.corner_ids], d.image_points, intr)[0] for d in dets])
M = m.M_from_T_base_end(np.stack([s.T_base_end_reported[s.index(d.view_id)] for d in dets]))
est = all_methods(m, C, M)["tsai"]
views = [RefineView(v, i, p, s.T_base_end_reported[k]) for k, (v, i, p) in
         enumerate(zip(s.view_ids, s.corner_ids, s.image_points))]
r = refine(mode=s.mode, object_points=obj, views=views, intrinsics=intr, T_x0=est.T_x, T_board0=est.T_board)
plan = plan_verification(load_result(result_from_refinement(r, target=s.target)), max_views=4, power=1 - 1e-12)
print(intr.as_vector().tolist())
print(r.T_x.ravel().tolist(), r.cov_x_6x6.ravel().tolist())
print(np.asarray(plan.poses).ravel().tolist())
"""


def _session():
    return make_corner_session(mode="eye_in_hand", n_views=12, seed=2, noise_px=0.3)


def test_repeated_calibrations_of_the_same_corners_agree_to_the_bit_and_keep_the_thread_count():
    s = _session()
    obj, dets = s.target.object_points(), s.detections()
    before = cv2.getNumThreads()
    runs = [calibrate_intrinsics(dets, obj) for _ in range(4)]
    assert cv2.getNumThreads() == before
    first = runs[0][0].as_vector()
    for intr, rms in runs[1:]:
        assert np.array_equal(intr.as_vector(), first), intr.as_vector() - first
        assert rms == runs[0][1]
    assert abs(first[0] - s.intrinsics.fx) < 5.0  # and it is a calibration (0.3 px corners, 12 views)


def test_a_calibration_and_its_verification_plan_repeat_exactly_in_fresh_interpreters_of_any_hashing():
    outs = []
    for hash_seed in ("1", "4"):
        env = dict(os.environ, PYTHONHASHSEED=hash_seed, PYTHONPATH=str(REPO))
        p = subprocess.run(
            [sys.executable, "-c", _SCRIPT], env=env, cwd=REPO, capture_output=True, text=True, timeout=300
        )
        assert p.returncode == 0, p.stderr[-2000:]
        outs.append(p.stdout)
    assert len(outs[0].splitlines()) == 3
    assert outs[0] == outs[1]
