"""A synthetic fleet: installs with dated eye-in-hand sessions and known truth, for ``handeye batch``.

:func:`write_fleet` writes ``ROOT/<install>/<YYYY-MM-DD>/`` vendor sessions, one rig per install,
each session with its ``ground_truth.json``. Faults by (install, session): ``bumps`` (the camera
moved on the flange from then on), ``broken`` (a pose line that does not load), ``shuffled`` (pose
lines permuted) and ``noisy`` (a worn arm). It returns the manifest (``ROOT/fleet_truth.json``).

See docs/fleet.md and, for faults in one session, docs/batch.md.
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
from ..targets import ChessboardSpec
from .scenarios import DEFAULT_TARGET, default_intrinsics, perturb_T_base_end, random_streams, sample_setup
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
    bad_time: tuple = (),
    modes: Optional[dict] = None,
    boards: Optional[dict] = None,
    start: str = "2026-01-05",
    days_between: int = 30,
) -> dict:
    """Write the fleet under ``root``.

    Write the fleet under ``root`` (see the module docstring) and return its manifest:
    ``{"sessions": [{"install", "session", "path", "T_end_cam", "T_base_board", "fault"}]}``.
    ``bumps``: {(install index, session index): (rotvec_deg, t_mm)}; ``broken`` / ``shuffled`` /
    ``noisy`` / ``bad_time``: (install index, session index) pairs. ``robot_noise``: (mm, deg) per axis.
    ``modes``: {(install index, session index): mounting mode}; ``boards``: {(install index, session index):
    (cols, rows) inner corners of a chessboard of 30 mm squares}: those sessions get a rig of their own
    (their ``T_x`` / ``T_board`` in the manifest under the mode's names).
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    bumps = dict(bumps or {})
    modes, boards = dict(modes or {}), dict(boards or {})
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
            if (i, j) in modes or (i, j) in boards:
                manifest["sessions"].append(
                    _write_other_rig(
                        out,
                        install=install,
                        session=day.isoformat(),
                        mode=modes.get((i, j), "eye_in_hand"),
                        board=boards.get((i, j)),
                        n_views=n_views,
                        image_size=image_size,
                        seed=seed * 1000 + 700 + 10 * i + j,
                        robot_noise=robot_noise,
                    )
                )
                if (i, j) in bad_time:
                    _as_native_with_bad_time(out)
                continue
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
            if (i, j) in bad_time:
                _as_native_with_bad_time(out)
            manifest["sessions"].append(
                {
                    "install": install,
                    "session": day.isoformat(),
                    "path": str(out),
                    "mode": "eye_in_hand",
                    "board": [DEFAULT_TARGET.cols, DEFAULT_TARGET.rows],
                    "T_end_cam": T_end_cam.tolist(),
                    "T_base_board": T_base_board.tolist(),
                    "fault": fault or ("bad_time" if (i, j) in bad_time else None),
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


def _write_other_rig(
    out: Path,
    *,
    install: str,
    session: str,
    mode: str,
    board: Optional[tuple],
    n_views: int,
    image_size: tuple,
    seed: int,
    robot_noise: tuple,
) -> dict:
    """Render a session of its own rig at ``out`` and return its manifest entry.

    The rig is of mounting mode ``mode`` and a chessboard of ``board`` inner corners (the fleet's board
    when None).
    """
    target = DEFAULT_TARGET if board is None else ChessboardSpec(int(board[0]), int(board[1]), DEFAULT_TARGET.square_m)
    write_vendor_session(
        out,
        mode=mode,
        n_views=n_views,
        seed=seed,
        target=target,
        intrinsics=default_intrinsics(*image_size),
        supersample=2,
        workers=1,
        overwrite=True,
        image_noise=2.0,
        robot_noise=robot_noise,
    )
    gt = json.loads((out / "ground_truth.json").read_text(encoding="utf-8"))
    x_name, board_name = ("T_end_cam", "T_base_board") if mode == "eye_in_hand" else ("T_base_cam", "T_end_board")
    return {
        "install": install,
        "session": session,
        "path": str(out),
        "mode": mode,
        "board": [target.cols, target.rows],
        x_name: gt[x_name],
        board_name: gt[board_name],
        "fault": None,
    }


#: the time stamp a ``bad_time`` session's first view carries: a number, but no time a clock can show
BAD_T_IMAGE = 1.0e20


def _as_native_with_bad_time(folder: Path) -> None:
    """Rewrite the vendor session at ``folder`` as a native session.yaml whose first view has a bad time.

    The same views, poses, board and mode; the first view's ``t_image`` is :data:`BAD_T_IMAGE`.
    """
    import yaml

    cfg = yaml.safe_load((folder / "config.yaml").read_text(encoding="utf-8"))
    board = cfg["checkerboard_args"]
    lines = [ln for ln in (folder / "poses.txt").read_text(encoding="utf-8").splitlines() if ln.strip()]
    views: list[dict[str, object]] = [
        {"id": str(k), "image": f"{k}.jpg", "pose": [float(x) for x in ln.split(",")]}
        for k, ln in enumerate(lines, start=1)
        if (folder / f"{k}.jpg").exists()
    ]
    views[0]["t_image"] = BAD_T_IMAGE
    doc = {
        "handeye_session": 1,
        "mode": cfg.get("mode", "eye_in_hand"),
        "target": {"type": "chessboard", "inner_corners": [board["XX"], board["YY"]], "square_m": board["L"]},
        "pose_format": {"rotation": "euler"},
        "views": views,
    }
    for name in ("poses.txt", "config.yaml"):
        (folder / name).unlink()
    atomic_write_text(folder / "session.yaml", yaml.safe_dump(doc, sort_keys=False))


#: how :func:`write_damaged_result` damages a result.json
DAMAGES = ("verdict_mapping", "invalid_json")


def write_damaged_result(folder, how: str = "verdict_mapping") -> Path:
    """Damage the result.json in ``folder`` (or write one there) and return its path.

    ``verdict_mapping`` makes its verdict a mapping (the rest of a real result kept), ``invalid_json``
    cuts the file in the middle.
    """
    if how not in DAMAGES:
        raise ValueError(f"unknown damage {how!r}; one of {DAMAGES}")
    path = Path(folder) / "result.json"
    try:
        text = path.read_text(encoding="utf-8")
        res = json.loads(text)
    except (OSError, ValueError):
        text, res = "", None
    if not isinstance(res, dict):
        res = {"handeye_result": 1, "status": "failed", "mode": "eye_in_hand", "findings": []}
        text = to_json(res)
    if how == "verdict_mapping":
        res["verdict"] = {"PASS": True}
        text = to_json(res) + "\n"
    else:
        text = text[: max(1, len(text) // 2)]
    atomic_write_text(path, text)
    return path
