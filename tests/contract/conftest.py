"""Real result folders for the contract's tests: a rendered session calibrated with the refinement (its
intrinsics and covariances), a pose-only session and two failed runs (a pipeline failure, an unreadable
session), each written by the real workflow."""

import shutil
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def results(tmp_path_factory) -> dict:
    """name -> result folder: ``images`` (6 rendered views, refined, with covariances), ``pose_only``,
    ``failed`` (too few tracker views) and ``unreadable`` (an empty session folder). Copy before changing."""
    from handeye.sim.poses import make_tracker_session
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session
    from handeye.workflow import calibrate_session

    root = tmp_path_factory.mktemp("contract")
    write_vendor_session(
        root / "images_s",
        mode="eye_in_hand",
        n_views=8,
        seed=3,
        intrinsics=default_intrinsics(400, 300),
        supersample=2,
        workers=1,
    )
    calibrate_session(root / "images_s", out_dir=root / "images", report=False)
    ts = make_tracker_session(mode="eye_to_hand", n_views=12, seed=2)
    ts.write(root / "pose_only_s", state_sigma=False)
    calibrate_session(root / "pose_only_s", out_dir=root / "pose_only", report=False)
    make_tracker_session(mode="eye_in_hand", n_views=2, seed=2).write(root / "failed_s")
    calibrate_session(root / "failed_s", out_dir=root / "failed", report=False, diagnostics=False)
    (root / "unreadable_s").mkdir()
    calibrate_session(root / "unreadable_s", out_dir=root / "unreadable", report=False, diagnostics=False)
    return {name: root / name for name in ("images", "pose_only", "failed", "unreadable")}


@pytest.fixture
def copy_result(results, tmp_path):
    """``copy_result(name) -> folder``: a copy of one of :func:`results`' folders to change."""

    def make(name: str = "images") -> Path:
        dest = tmp_path / name
        shutil.copytree(results[name], dest)
        return dest

    return make
