"""Issue 5's check: a simulated automatic collection, then `handeye calibrate`, scored against
the ground truth the simulators wrote into the session."""
import json

import numpy as np
import pytest

from handeye.cli import main
from handeye.frames import pose_error


@pytest.mark.parametrize("mode", ["eye_in_hand", "eye_to_hand"])
def test_simulated_collection_calibrates_to_the_simulated_accuracy(tmp_path, mode):
    out = tmp_path / "col"
    assert main(["-q", "collect", str(out), "--mode", mode, "--camera", "sim", "--robot", "sim", "--auto"]) == 0
    truth = json.loads((out / "ground_truth.json").read_text())
    assert main(["-q", "calibrate", str(out), "--out", str(tmp_path / "res"), "--no-report"]) == 0
    res = json.loads((tmp_path / "res" / "result.json").read_text())
    name = {"eye_in_hand": "T_end_cam", "eye_to_hand": "T_base_cam"}[mode]
    r, t = pose_error(np.asarray(res[name]), np.asarray(truth[name]))
    sig_t = np.linalg.norm(res["refinement"]["sigma_trans_mm"])
    sig_r = np.linalg.norm(res["refinement"]["sigma_rot_deg"])
    # the simulated arm reports its pose with noise: the error must stay within ~4 predicted sigmas
    assert t < max(4 * sig_t, 0.5) and r < max(4 * sig_r, 0.1), (r, t, sig_r, sig_t)
    assert t < 2.0 and r < 0.2
