"""Shared test fixtures. Real datasets live in ../shared/data (never copied into the repo).

Tests that need them skip cleanly when that folder is absent, except under CI (``CI=true``), where a
missing dataset is a failure: CI always has ../shared beside the clone, so a skip there would hide
that the real-data tests never ran.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("HANDEYE_SHARED_DATA", REPO.parent / "shared" / "data"))


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


def require_dataset(name: str) -> Path:
    """Path of ../shared/data/<name>; skip when it is absent, fail when it is absent under CI."""
    path = SHARED_DATA / name
    if not path.is_dir():
        msg = f"real dataset {name} not available ({path} missing)"
        if in_ci():
            pytest.fail(msg + "; CI must run the real-data tests", pytrace=False)
        pytest.skip(msg)
    return path


@pytest.fixture(scope="session")
def shared_dataset():
    """``shared_dataset(name)`` -> path of ../shared/data/<name>, or skip the test when absent."""
    return require_dataset


@pytest.fixture(autouse=True)
def _no_stray_outputs(monkeypatch, tmp_path):
    # commands that default to ./reports write into the test's own folder
    monkeypatch.chdir(tmp_path)


def _session_with_board(session: Path, dest: Path, *, cols: int, rows: int, square_m: float = 0.03) -> Path:
    """A vendor session at ``dest`` that links ``session``'s images and poses but states another board."""
    import yaml

    dest.mkdir()
    for f in session.iterdir():
        (dest / f.name).symlink_to(f)
    (dest / "config.yaml").unlink()
    (dest / "config.yaml").write_text(yaml.safe_dump({"checkerboard_args": {"XX": cols, "YY": rows, "L": square_m}}))
    return dest


@pytest.fixture(scope="session")
def session_with_board():
    """``session_with_board(session, dest, cols=, rows=)``: the session's views under another stated board."""
    return _session_with_board


# ------------------------------------------------------------------------------------------------ cells
def assemble_cell(solo: dict) -> dict:
    """A cell result.json (``kind: cell``) made of one-camera result folders ``{camera name: folder}``.

    Each camera's entry is its solo result as written (its version key is the cell's); every pair of
    cameras of one mounting mode (fixed to each other) gets ``T_a_b`` with its covariance propagated from
    the two X's (``Ad(T_a_b^-1) C_a Ad^T + C_b``, right tangent); ``joint_covariance`` holds the X blocks.
    """
    import json

    import numpy as np

    from handeye.frames import inv_T, se3_adjoint

    cams = {}
    for name, folder in solo.items():
        entry = json.loads((Path(folder) / "result.json").read_text())
        entry.pop("handeye_result")
        cams[name] = entry

    def x_cov(e):
        ref = e["refinement"]
        return np.asarray(e[e["hand_eye"]["name"]]), np.asarray(ref.get("cov_x_6x6_verdict") or ref["cov_x_6x6"])

    pairs, names = {}, list(cams)
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            if cams[a]["mode"] != cams[b]["mode"]:
                continue
            (Ta, Ca), (Tb, Cb) = x_cov(cams[a]), x_cov(cams[b])
            T_ab = inv_T(Ta) @ Tb
            Ad = se3_adjoint(inv_T(T_ab))
            C = Ad @ Ca @ Ad.T + Cb
            pairs[f"{a}/{b}"] = {
                "name": f"T_{a}_{b}",
                "matrix": T_ab.tolist(),
                "cov_6x6": C.tolist(),
                "translation_mm": (1e3 * T_ab[:3, 3]).tolist(),  # as handeye.cell writes them beside the matrix
                "sigma_rot_deg": np.degrees(np.sqrt(np.diag(C)[:3])).tolist(),
                "sigma_trans_mm": (1e3 * np.sqrt(np.diag(C)[3:])).tolist(),
            }
    blocks = [f"cameras.{n}.{cams[n]['hand_eye']['name']}" for n in names]
    cov = np.zeros((6 * len(names), 6 * len(names)))
    for k, n in enumerate(names):
        cov[6 * k : 6 * k + 6, 6 * k : 6 * k + 6] = x_cov(cams[n])[1]
    verdicts = [str(cams[n].get("verdict") or "") for n in names]
    worst = next((v for v in ("REFUSED", "FAIL", "WARN", "PASS") if v in verdicts), None)
    return {
        "handeye_result": 1,
        "kind": "cell",
        "status": "ok",
        "mode": "cell",
        "verdict": worst,
        "cameras": cams,
        "camera_pairs": pairs,
        "joint_covariance": {"blocks": blocks, "sizes": [6] * len(names), "matrix": cov.tolist()},
    }


@pytest.fixture(scope="session")
def cell(tmp_path_factory) -> dict:
    """A calibrated cell of three cameras of one simulated arm, each calibrated by the real workflow.

    ``wrist`` (eye_in_hand, 8 rendered views at 400x300), ``fixed1`` (eye_to_hand, 8 rendered views),
    ``fixed2`` (eye_to_hand, a 12-view pose-only session). Keys: ``cell`` (a folder holding the cell's
    result.json, :func:`assemble_cell`), ``solo`` (name -> its one-camera result folder), ``truth`` (name ->
    its ground truth dict or None) and ``verify`` (name -> a 4-view rendered session of that camera's rig in
    a folder named after the camera, for wrist and fixed1). Copy before changing.
    """
    import json

    from handeye.sim.poses import make_tracker_session
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session
    from handeye.workflow import calibrate_session

    root = tmp_path_factory.mktemp("cell")
    intr = default_intrinsics(400, 300)
    solo, truth, verify = {}, {}, {}
    for name, mode, seed in (("wrist", "eye_in_hand", 3), ("fixed1", "eye_to_hand", 5)):
        s = write_vendor_session(
            root / "sessions" / name, mode=mode, n_views=8, seed=seed, intrinsics=intr, supersample=2, workers=1
        )
        truth[name] = json.loads((s / "ground_truth.json").read_text())
        x_name = "T_end_cam" if mode == "eye_in_hand" else "T_base_cam"
        board = "T_base_board" if mode == "eye_in_hand" else "T_end_board"
        verify[name] = write_vendor_session(
            root / "verify" / name,
            mode=mode,
            n_views=4,
            seed=200 + seed,
            image_noise=2.0,
            intrinsics=intr,
            supersample=2,
            workers=1,
            rig=(truth[name][x_name], truth[name][board]),
        )
    make_tracker_session(mode="eye_to_hand", n_views=12, seed=4).write(root / "sessions" / "fixed2", state_sigma=False)
    truth["fixed2"] = None
    for name in ("wrist", "fixed1", "fixed2"):
        solo[name] = root / "solo" / name
        calibrate_session(root / "sessions" / name, out_dir=solo[name], report=False)
    (root / "cell").mkdir()
    (root / "cell" / "result.json").write_text(json.dumps(assemble_cell(solo)))
    return {"cell": root / "cell", "solo": solo, "truth": truth, "verify": verify, "sessions": root / "sessions"}
