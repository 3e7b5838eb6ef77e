"""A synthetic fleet: installs with dated eye-in-hand sessions and known truth, for ``handeye batch``.

:func:`write_fleet` writes ``ROOT/<install>/<YYYY-MM-DD>/`` vendor sessions. Every install is one
rig (its own ``T_end_cam`` and ``T_base_board`` from :func:`handeye.sim.scenarios.sample_setup`);
its sessions reuse a few rendered view sets (the images depend only on each view's ``T_cam_board``),
with the robot poses that the install's rig needs to see the board so:
``T_base_end_i = T_base_board @ inv(T_cam_board_i) @ inv(T_end_cam)``, plus iid robot noise.
Each session's ``ground_truth.json`` holds its true ``T_end_cam`` and ``T_base_board``.

Faults, by (install index, session index): ``bumps`` move the camera on the flange from that session
on (``T_end_cam @ T_from_rotvec(rot, t)``, the bump's rotation vector in deg and translation in mm);
``broken`` sessions get a pose line with five numbers (the session does not load); ``shuffled``
sessions get their pose lines permuted (images carry other views' poses); ``noisy`` sessions get
the robot noise ``noisy_robot`` (a worn arm: the result fails QA on its uncertainty). :func:`write_fleet`
returns the manifest (also written as ``ROOT/fleet_truth.json``).
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import shutil
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..conventions import VENDOR_POSE_FORMAT, pose_values_from_T
from ..frames import T_from_rotvec, inv_T
from ..output import atomic_write_text, to_json
from .scenarios import default_intrinsics, perturb_T_base_end, random_streams, sample_setup
from .vendor import write_vendor_session

#: the default bump: 1.5 deg about a tilted axis and 3 mm, in the camera frame
DEFAULT_BUMP = ((0.9, -0.9, 0.6), (2.0, -1.5, 1.5))


def write_fleet(
    root,
    *,
    n_installs: int = 4,
    sessions_per_install: int = 3,
    n_views: int = 8,
    image_size: tuple[int, int] = (640, 360),
    n_view_sets: int = 3,
    seed: int = 0,
    robot_noise: tuple[float, float] = (0.1, 0.02),
    bumps: Optional[dict] = None,
    broken: tuple = (),
    shuffled: tuple = (),
    noisy: tuple = (),
    noisy_robot: tuple[float, float] = (4.0, 1.0),
    start: str = "2026-01-05",
    days_between: int = 30,
) -> dict:
    """Write the fleet under ``root``.

    Write the fleet under ``root`` (see the module docstring) and return its manifest:
    ``{"sessions": [{"install", "session", "path", "T_end_cam", "T_base_board", "fault"}]}``.
    ``bumps``: {(install index, session index): (rotvec_deg, t_mm)}; ``broken`` / ``shuffled`` /
    ``noisy``: (install index, session index) pairs. ``robot_noise``: (mm, deg) per axis.
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    bumps = dict(bumps or {})
    sets_dir = root / ".view_sets"  # hidden: not a session of the fleet
    view_sets = []
    for k in range(n_view_sets):
        p = write_vendor_session(
            sets_dir / f"set{k}",
            n_views=n_views,
            seed=seed * 1000 + k,
            intrinsics=default_intrinsics(*image_size),
            supersample=2,
            workers=1,
            overwrite=True,
            image_noise=2.0,
        )
        gt = json.loads((p / "ground_truth.json").read_text(encoding="utf-8"))
        view_sets.append((p, gt))
    day0 = _dt.date.fromisoformat(start)
    manifest: dict[str, list[dict[str, Any]]] = {"sessions": []}
    for i in range(n_installs):
        install = f"cell-{i + 1:02d}"
        rig = sample_setup(mode="eye_in_hand", rng=random_streams(seed * 1000 + 500 + i)["geometry"])
        T_end_cam, T_base_board = rig["T_x"], rig["T_board"]
        for j in range(sessions_per_install):
            if (i, j) in bumps:
                rot_deg, t_mm = bumps[(i, j)]
                T_end_cam = T_end_cam @ T_from_rotvec(np.radians(rot_deg), np.asarray(t_mm, float) * 1e-3)
            day = day0 + _dt.timedelta(days=days_between * j + i)
            out = root / install / day.isoformat()
            src, gt = view_sets[(i + j) % n_view_sets]
            fault = next(
                (
                    name
                    for name, where in (("broken", broken), ("shuffled", shuffled), ("noisy", noisy), ("bumped", bumps))
                    if (i, j) in where
                ),
                None,
            )
            _write_session(
                out,
                src,
                gt,
                T_end_cam,
                T_base_board,
                robot_noise=noisy_robot if fault == "noisy" else robot_noise,
                rng=random_streams(seed * 1000 + 100 * i + j)["robot_noise"],
                fault=fault,
            )
            manifest["sessions"].append(
                {
                    "install": install,
                    "session": day.isoformat(),
                    "path": str(out),
                    "T_end_cam": T_end_cam.tolist(),
                    "T_base_board": T_base_board.tolist(),
                    "fault": fault,
                }
            )
    shutil.rmtree(sets_dir, ignore_errors=True)
    atomic_write_text(root / "fleet_truth.json", to_json(manifest) + "\n")
    return manifest


def _write_session(
    out: Path,
    src: Path,
    gt: dict,
    T_end_cam: np.ndarray,
    T_base_board: np.ndarray,
    *,
    robot_noise,
    rng,
    fault: Optional[str],
) -> None:
    out.mkdir(parents=True, exist_ok=True)
    ids = sorted(gt["views"], key=int)
    T_true = np.stack(
        [T_base_board @ inv_T(np.asarray(gt["views"][v]["T_cam_board_true"])) @ inv_T(T_end_cam) for v in ids]
    )  # shape (N, 4, 4)
    T_reported = perturb_T_base_end(T_true, rng=rng, sigma_mm=robot_noise[0], sigma_deg=robot_noise[1])
    lines = [",".join(f"{x:.9f}" for x in pose_values_from_T(T, VENDOR_POSE_FORMAT)) for T in T_reported]
    if fault == "shuffled":  # images carry other views' poses, in no constant shift
        order = rng.permutation(len(lines))
        while np.any(order == np.arange(len(lines))) or len(set(np.diff(order) % len(lines))) == 1:
            order = rng.permutation(len(lines))
        lines = [lines[k] for k in order]
    if fault == "broken":
        lines[2] = ",".join(lines[2].split(",")[:5])
    for v in ids:
        name = gt["views"][v]["image"]
        if (out / name).exists():
            (out / name).unlink()
        try:
            os.link(src / name, out / name)
        except OSError:
            shutil.copyfile(src / name, out / name)
    shutil.copyfile(src / "config.yaml", out / "config.yaml")
    atomic_write_text(out / "poses.txt", "\n".join(lines) + "\n")
    truth = {
        "handeye_synthetic_ground_truth": 1,
        "mode": "eye_in_hand",
        "T_end_cam": T_end_cam.tolist(),
        "T_base_board": T_base_board.tolist(),
        "fault": fault,
        "robot_noise_mm": robot_noise[0],
        "robot_noise_deg": robot_noise[1],
        "intrinsics": gt["intrinsics"],
        "target": gt["target"],
    }
    atomic_write_text(out / "ground_truth.json", to_json(truth) + "\n")
