"""Simulated cells: several cameras of one arm, the same robot poses in every camera's session.

:func:`make_cell` draws one eye-in-hand corner-level session (:func:`handeye.sim.corners.make_corner_session`:
the arm, its robot error, the wrist camera, the board on the table and the poses), then mounts a board on the
back of the flange, facing away from the table, and places the fixed cameras on a cone behind it, each seeing
it in most views; from three cameras on the wrist camera is one of the cell's. Every camera sees its board
through the same true robot poses; a view a camera does not see its whole board in is hidden for it.
:func:`write_cell` renders it: one session folder per camera (session.yaml with the view ids, poses and
joint angles), ``cell.yaml`` and ground_truth.json files.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..camera import pixels_from_board_points
from ..errors import ConfigError
from ..frames import R_from_rotvec, inv_T, make_T, se3_exp
from ..mounting import mounting
from .corners import CornerSession, _frozen, make_corner_session
from .scenarios import board_center
from .vendor import clear_previous_session

#: the cameras of an N-camera cell: (name, mode); fixed cameras first, a wrist camera from 3 on
LAYOUTS = {
    2: (("cam1", "eye_to_hand"), ("cam2", "eye_to_hand")),
    3: (("cam1", "eye_to_hand"), ("cam2", "eye_to_hand"), ("wrist", "eye_in_hand")),
    4: (("cam1", "eye_to_hand"), ("cam2", "eye_to_hand"), ("cam3", "eye_to_hand"), ("wrist", "eye_in_hand")),
}
MARGIN_PX = 10.0
MIN_SEEN_SHARE = 0.6  # a placed camera sees its whole board in at least this share of the views


@dataclass(frozen=True)
class SimCell:
    """A simulated cell: one corner-level session per camera (shared view ids and robot poses) and the truth."""

    names: tuple[str, ...]
    sessions: tuple[CornerSession, ...]

    def session(self, name: str) -> CornerSession:
        return self.sessions[self.names.index(name)]


def _visible(T_cam_board: np.ndarray, obj: np.ndarray, s: CornerSession) -> np.ndarray:
    """(N,) the whole board in the image, in front of the camera, seen from its printed side within 70 deg."""
    ok = np.zeros(len(T_cam_board), bool)
    for k, T in enumerate(T_cam_board):
        p = obj @ T[:3, :3].T + T[:3, 3]
        if np.any(p[:, 2] <= 0.05):
            continue
        normal_cam = T[:3, 2]  # board z in the camera frame: it points away from a camera that sees the front
        ray = p.mean(axis=0) / np.linalg.norm(p.mean(axis=0))
        if float(normal_cam @ ray) < np.cos(np.radians(70.0)):
            continue
        uv = pixels_from_board_points(T, obj, s.intrinsics)
        w, h = s.intrinsics.width, s.intrinsics.height
        ok[k] = bool(np.all((uv > MARGIN_PX) & (uv < np.array([w, h]) - MARGIN_PX)))
    return ok


def _project(
    s: CornerSession, T_x: np.ndarray, T_board: np.ndarray, mode: str, rng, noise_px: float, jitter=(0.0, 0.0)
) -> CornerSession:
    """The session of a camera at ``T_x`` seeing ``T_board`` through ``s``'s true robot poses.

    ``jitter`` (rad, m per axis): the camera sees each view's flange at ``T_base_end_true · Exp(delta)``, ``delta``
    drawn per view (its own instant of a moving arm); the session's true poses stay the shared ones.
    """
    mount = mounting(mode)
    obj = s.target.object_points()
    T_be = s.T_base_end_true
    if any(jitter):
        sd = np.repeat(np.asarray(jitter, float), 3)
        T_be = np.stack([T @ se3_exp(rng.normal(0.0, 1.0, 6) * sd) for T in T_be])
    T_cb = mount.predict_T_cam_board(T_x, T_board, T_be)
    seen = _visible(T_cb, obj, s)
    ids, pts = [], []
    for k in range(s.n_views):
        if not seen[k]:
            ids.append(_frozen(np.zeros(0, int)))
            pts.append(_frozen(np.zeros((0, 2))))
            continue
        uv = pixels_from_board_points(T_cb[k], obj, s.intrinsics)
        ids.append(_frozen(np.arange(len(obj))))
        pts.append(_frozen(uv + rng.normal(0.0, noise_px, uv.shape) if noise_px > 0 else uv))
    hidden = tuple(v for v, ok in zip(s.view_ids, seen, strict=True) if not ok)
    return replace(
        s,
        mode=mode,
        T_x_true=_frozen(T_x),
        T_board_true=_frozen(T_board),
        corner_ids=tuple(ids),
        image_points=tuple(pts),
        hidden_view_ids=hidden,
        noise_px=float(noise_px),
    )


def _look_at(position: np.ndarray, target: np.ndarray, roll_rad: float) -> np.ndarray:
    """T_base_cam of a camera at ``position`` whose optical axis passes through ``target``, rolled about it."""
    z = (target - position) / np.linalg.norm(target - position)
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=1) @ R_from_rotvec(np.array([0.0, 0.0, roll_rad]))
    return make_T(R, position)


def _flange_board(wrist: CornerSession, rng) -> np.ndarray:
    """T_end_board: a board on the back of the flange, its printed face away from the wrist camera's view."""
    a = wrist.T_x_true[:3, 2]  # the wrist camera's optical axis in the end frame
    z = a / np.linalg.norm(a)  # board z (into the board) along it: the face looks back, away from the table
    x = np.cross(z, [1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=1) @ R_from_rotvec(np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)]))
    centre = -rng.uniform(0.03, 0.06) * z + rng.uniform(-0.02, 0.02, 3) * np.array([1.0, 1.0, 0.0])
    return make_T(R, centre - R @ board_center(wrist.target))


def _fixed_camera(wrist: CornerSession, T_end_board: np.ndarray, k: int, n_fixed: int, rng) -> Optional[np.ndarray]:
    """T_base_cam of fixed camera k of n_fixed behind the flange board, on a cone about its mean normal."""
    T_base_board = wrist.T_base_end_true @ T_end_board  # shape (N, 4, 4)
    obj = wrist.target.object_points()
    centre = (T_base_board[:, :3, :3] @ board_center(wrist.target) + T_base_board[:, :3, 3]).mean(axis=0)
    back = -T_base_board[:, :3, 2].mean(axis=0)  # from the board towards its viewers
    back /= np.linalg.norm(back)
    e1 = np.cross(back, [0.0, 0.0, 1.0]) if abs(back[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(back, e1)
    best, best_share = None, -1.0
    for _ in range(30):
        cone = np.radians(rng.uniform(12.0, 35.0))
        az = 2 * np.pi * k / n_fixed + rng.uniform(-0.4, 0.4)
        w = np.cos(cone) * back + np.sin(cone) * (np.cos(az) * e1 + np.sin(az) * e2)
        T = _look_at(centre + rng.uniform(0.8, 1.2) * w, centre, rng.uniform(-0.3, 0.3))
        T_cb = mounting("eye_to_hand").predict_T_cam_board(T, T_end_board, wrist.T_base_end_true)
        share = float(_visible(T_cb, obj, wrist).mean())
        if share > best_share:
            best, best_share = T, share
        if share >= 0.9:
            break
    return best if best_share >= MIN_SEEN_SHARE else None


def make_cell(
    n_cameras: int = 3,
    *,
    n_views: int = 40,
    seed: int = 0,
    noise_px: float = 0.3,
    robot_error: str = "kinematic",
    arm: str = "ur5e",
    view_jitter: tuple[float, float] = (0.0, 0.0),
    **session_options,
) -> SimCell:
    """A corner-level cell of ``n_cameras`` (2-4, :data:`LAYOUTS`) with ground truth; see the module docstring.

    ``view_jitter`` (deg, mm per axis): each fixed camera sees the flange of each view moved by its own draw of
    that size (the arm seen at another instant by each camera); the wrist camera sees the view's true pose.
    """
    if n_cameras not in LAYOUTS:
        raise ConfigError("a simulated cell has 2-4 cameras", expected="2, 3 or 4", received=str(n_cameras))
    wrist = make_corner_session(
        mode="eye_in_hand",
        n_views=n_views,
        seed=seed,
        noise_px=noise_px,
        robot_error=robot_error,
        arm=arm,
        **session_options,
    )
    rng = np.random.default_rng([seed, 27])
    layout = LAYOUTS[n_cameras]
    n_fixed = sum(1 for _n, m in layout if m == "eye_to_hand")
    for _attempt in range(10):
        T_end_board = _flange_board(wrist, rng)
        fixed = [_fixed_camera(wrist, T_end_board, k, n_fixed, rng) for k in range(n_fixed)]
        if all(T is not None for T in fixed):
            break
    else:
        raise ConfigError(
            "no place for the fixed cameras that see the flange board in most views",
            expected=f"{n_fixed} cameras each seeing the board in {MIN_SEEN_SHARE:.0%} of the views",
            received=f"seed {seed}",
            hint="try another seed",
        )
    sessions = []
    it = iter(fixed)
    for _name, mode in layout:
        if mode == "eye_in_hand":
            sessions.append(wrist)
        else:
            T = next(it)
            assert T is not None, "checked above"
            jitter = (np.radians(view_jitter[0]), 1e-3 * view_jitter[1])
            sessions.append(_project(wrist, T, T_end_board, mode, rng, noise_px, jitter))
    return SimCell(names=tuple(n for n, _m in layout), sessions=tuple(sessions))


def truth_dict(cell: SimCell) -> dict:
    """The cell's ground truth: each camera's X and board under their frame names, and T_a_b of every pair."""
    cams = {}
    for name, s in zip(cell.names, cell.sessions, strict=True):
        cams[name] = {"mode": s.mode, s.x_name: s.T_x_true.tolist(), s.board_name: s.T_board_true.tolist()}
    pairs = {}
    for i, a in enumerate(cell.names):
        for b in cell.names[i + 1 :]:
            sa, sb = cell.session(a), cell.session(b)
            if mounting(sa.mode).fixed_frame == mounting(sb.mode).fixed_frame:
                pairs[f"{a}/{b}"] = {"name": f"T_{a}_{b}", "matrix": (inv_T(sa.T_x_true) @ sb.T_x_true).tolist()}
    first = cell.sessions[0]
    return {
        "handeye_synthetic_ground_truth": 1,
        "kind": "cell",
        "cameras": cams,
        "camera_pairs": pairs,
        "views": {v: {"T_base_end_true": first.T_base_end_true[k].tolist()} for k, v in enumerate(first.view_ids)},
        "robot_error": first.robot_model or {"model": first.robot_error},
        "seed": first.seed,
    }


def _refuse_a_session_there(out: Path, *, overwrite: bool) -> None:
    """Refuse (unless ``overwrite``) an ``out`` holding a session or a cell: its own, or a session one level down."""
    files = ("cell.yaml", "ground_truth.json", "session.yaml", "poses.txt", "config.yaml")
    found = [out / n for n in files if (out / n).exists()]
    found += [p for n in ("session.yaml", "poses.txt") for p in sorted(out.glob(f"*/{n}"))]
    if found and not overwrite:
        raise ConfigError(
            "output folder already holds a session or a cell",
            path=out,
            expected="an empty or new folder",
            received=f"{len(found)} session files (e.g. {found[0].relative_to(out)})",
            hint="choose another folder, or write over it (handeye simulate --force; overwrite=True)",
        )


def write_cell(
    out_dir,
    n_cameras: int = 3,
    *,
    n_views: int = 40,
    seed: int = 0,
    robot_error: str = "kinematic",
    arm: str = "ur5e",
    image_noise: float = 0.0,
    workers: int = 2,
    outlier_views: tuple = (),
    robot_noise: tuple = (0.0, 0.0),
    overwrite: bool = False,
) -> Path:
    """Render a cell: ``out_dir/<camera>/`` sessions (rendered images), ``cell.yaml`` and ground truth.

    Each camera's session.yaml lists the views it sees its whole board in (ids shared by the cell), with
    the reported robot poses and, with the kinematic robot error, the encoder joint angles and ``robot:``;
    ``out_dir/ground_truth.json`` holds the cell's truth (:func:`truth_dict`), each camera folder its own.
    ``outlier_views``: ids given a gross robot pose error (seen by every camera); ``robot_noise``: (mm, deg)
    per axis of the iid robot error. An ``out_dir`` that holds a session or a cell (its own files, or a
    session in a sub-folder) is refused unless ``overwrite``; then its camera folders' session files are
    removed before they are written again. Returns ``out_dir``.
    """
    import cv2
    import yaml

    from ..conventions import VENDOR_POSE_FORMAT, pose_values_from_T
    from ..output import atomic_write_bytes, atomic_write_text, to_json
    from .render import render_view

    cell = make_cell(
        n_cameras,
        n_views=n_views,
        seed=seed,
        noise_px=0.0,
        robot_error=robot_error,
        arm=arm,
        outlier_views=tuple(outlier_views),
        **({"robot_noise": tuple(robot_noise)} if any(robot_noise) else {}),
    )
    out = Path(out_dir)
    _refuse_a_session_there(out, overwrite=overwrite)
    out.mkdir(parents=True, exist_ok=True)
    arm_name: Optional[str] = arm if robot_error == "kinematic" else None
    for name, s in zip(cell.names, cell.sessions, strict=True):
        folder = out / name
        folder.mkdir(exist_ok=True)
        clear_previous_session(folder, overwrite=True)  # refused above unless overwrite
        T_cb = s.T_cam_board_true
        views: list[dict] = []
        for k, vid in enumerate(s.view_ids):
            if vid in s.hidden_view_ids:
                continue
            img = render_view(
                s.target,
                s.intrinsics,
                T_cb[k],
                noise_sigma=image_noise,
                rng=np.random.default_rng([seed, k, len(views)]),
                channels=3,
            )
            ok, buf = cv2.imencode(".png", img)
            if not ok:  # pragma: no cover - cv2 always encodes png
                raise ConfigError("image encoding failed", expected="a .png image", received="cv2.imencode False")
            atomic_write_bytes(folder / f"{vid}.png", buf.tobytes())
            view = {
                "id": vid,
                "image": f"{vid}.png",
                "pose": [round(float(x), 9) for x in pose_values_from_T(s.T_base_end_reported[k], VENDOR_POSE_FORMAT)],
            }
            if s.joints_encoder is not None:
                view["joints"] = [float(x) for x in s.joints_encoder[k]]
            views.append(view)
        doc = {"handeye_session": 1, "mode": s.mode, "target": s.target.to_dict(), "pose_format": {"rotation": "euler"}}
        if arm_name is not None:
            doc["robot"] = arm_name
        doc["views"] = views
        atomic_write_text(folder / "session.yaml", yaml.safe_dump(doc, sort_keys=False))
        truth = {
            "handeye_synthetic_ground_truth": 1,
            "mode": s.mode,
            s.x_name: s.T_x_true.tolist(),
            s.board_name: s.T_board_true.tolist(),
            "intrinsics": s.intrinsics.to_dict(),
            "hidden_view_ids": list(s.hidden_view_ids),
            "outlier_view_ids": list(s.outlier_view_ids),
        }
        atomic_write_text(folder / "ground_truth.json", json.dumps(truth, indent=1) + "\n")
    cfg: dict[str, object] = {"cell": {"sessions": list(cell.names)}}
    if arm_name is not None:
        cfg["robot"] = arm_name
    atomic_write_text(out / "cell.yaml", yaml.safe_dump(cfg, sort_keys=False))
    atomic_write_text(out / "ground_truth.json", to_json(truth_dict(cell)) + "\n")
    return out
