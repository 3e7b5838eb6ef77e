"""A rendered synthetic session on disk in the vendor layout, with ``ground_truth.json``.

:func:`write_vendor_session` renders the geometry of :func:`handeye.sim.corners.make_corner_session`
(same seed, same options) with :mod:`handeye.sim.render` and writes ``1.jpg .. N.jpg``,
``poses.txt``, ``config.yaml`` and ``ground_truth.json``, each atomically. Targets the vendor layout cannot
describe (ChArUco, circle grids, markers) get a native ``session.yaml`` with the same views and poses instead
of ``poses.txt`` and ``config.yaml``.
"""

from __future__ import annotations

import logging
import math
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Optional, Sequence, Union

import cv2
import yaml

from ..camera import Intrinsics
from ..collect.session_writer import intrinsics_header
from ..conventions import VENDOR_POSE_FORMAT, pose_values_from_T
from ..errors import ConfigError
from ..mounting import mounting
from ..output import atomic_write_bytes, atomic_write_text, provenance, to_json
from ..targets import ChessboardSpec
from . import render
from .corners import make_corner_session
from .scenarios import DEFAULT_INTRINSICS, DEFAULT_TARGET, random_streams

log = logging.getLogger(__name__)

_VENDOR_FILE_RE = r"^\d+\.(jpg|png)$"


def clear_previous_session(out: Path, *, overwrite: bool) -> None:
    """Remove the session files a simulation wrote in ``out`` before (refused unless ``overwrite``)."""
    names = [p.name for p in out.iterdir()] if out.exists() else []
    ours = [
        n
        for n in names
        if re.match(_VENDOR_FILE_RE, n) or n in ("poses.txt", "config.yaml", "session.yaml", "ground_truth.json")
    ]
    if not ours:
        return
    if not overwrite:
        raise ConfigError(
            "output folder already holds a session",
            path=out,
            expected="an empty or new folder",
            received=f"{len(ours)} session files (e.g. {ours[0]})",
            hint="choose another folder, or write over it (handeye simulate --force; overwrite=True)",
        )
    for n in ours:
        (out / n).unlink()


def write_vendor_session(
    out_dir,
    *,
    mode: str = "eye_in_hand",
    n_views: int = 20,
    seed: int = 0,
    image_noise: float = 0.0,
    blur_sigma_px: float = 0.0,
    gamma: float = 1.0,
    robot_noise: tuple[float, float] = (0.0, 0.0),
    hidden_views: Sequence[str] = (),
    outlier_views: Union[int, Sequence[str]] = 0,
    image_format: str = "jpg",
    target: ChessboardSpec = DEFAULT_TARGET,
    intrinsics: Optional[Intrinsics] = None,
    supersample: int = 4,
    jpeg_quality: int = 95,
    overwrite: bool = False,
    workers: int = 2,
    robot_error: str = "iid",
    arm: str = "rm65",
    **view_options,
) -> Path:
    """Render a synthetic session in the vendor layout.

    Render a synthetic session in the vendor layout (or, for a target other than a chessboard, as a native
    session.yaml with the same poses) and return its folder.

    Writes ``1.jpg .. N.jpg`` (or ``.png``; BGR, JPEG quality ``jpeg_quality``), ``poses.txt``
    (line k = reported ``T_base_end`` of k.jpg as ``x,y,z,rx,ry,rz``, metres and radians,
    R = Rz·Ry·Rx, ``%.9f``), ``config.yaml`` (``checkerboard_args: {XX, YY, L}`` and ``mode``) and
    ``ground_truth.json`` (true hand-eye and board under their frame names, intrinsics, per-view
    true/reported robot poses, true ``T_cam_board``, hidden/outlier flags, noise settings, seed).
    Every file is written atomically (temporary name in the folder, then ``os.replace``).

    The geometry is that of ``make_corner_session(mode=..., n_views=..., seed=..., ...)`` with the
    same arguments, so corner-level and image-level experiments share their ground truth.
    ``image_noise``: Gaussian noise sigma in grey levels; ``blur_sigma_px``: Gaussian blur; ``gamma``: the
    camera's tone curve (:func:`handeye.sim.render.render_view`; 1: grey proportional to light);
    ``hidden_views``: ids whose robot pose turns the camera away from the board (detection must
    fail there); ``outlier_views``: count or ids given a gross robot pose error; ``robot_error``
    (``iid`` | ``kinematic`` | ``none``) and ``arm``: the robot error model of
    :mod:`handeye.sim.robot_error` (kinematic: ground_truth.json also holds the true and nominal DH
    tables and each view's true and encoder joint angles; the vendor layout has no place for joints).
    """
    fmt = str(image_format).lower().lstrip(".")
    if fmt == "jpeg":
        fmt = "jpg"
    if fmt not in ("jpg", "png"):
        raise ConfigError("unsupported image format", expected="jpg | png", received=repr(image_format))
    levels = (image_noise, blur_sigma_px, *robot_noise)
    if not all(0 <= v < math.inf for v in levels):  # nan fails too: it would write poses of nan or render no noise
        raise ConfigError(
            "image noise, blur or robot noise not a finite number >= 0",
            expected="finite numbers >= 0",
            received=f"image_noise={image_noise}, blur_sigma_px={blur_sigma_px}, robot_noise={tuple(robot_noise)}",
        )
    intrinsics = DEFAULT_INTRINSICS if intrinsics is None else intrinsics
    session = make_corner_session(
        mode=mode,
        n_views=n_views,
        seed=seed,
        target=target,
        intrinsics=intrinsics,
        noise_px=0.0,
        robot_noise=robot_noise,
        outlier_views=outlier_views,
        hidden_views=hidden_views,
        robot_error=robot_error,
        arm=arm,
        **view_options,
    )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    clear_previous_session(out, overwrite=overwrite)

    T_cam_board = session.T_cam_board_true
    view_rngs = random_streams(seed)["image_noise"].spawn(session.n_views)
    encode_params = [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)] if fmt == "jpg" else []
    render.undistorted_sample_grid(intrinsics, supersample=supersample)  # build the cache once

    def render_one(k: int) -> str:
        img = render.render_view(
            target,
            intrinsics,
            T_cam_board[k],
            supersample=supersample,
            blur_sigma_px=blur_sigma_px,
            noise_sigma=image_noise,
            rng=view_rngs[k],
            channels=3,
            gamma=gamma,
        )
        ok, buf = cv2.imencode("." + fmt, img, encode_params)
        if not ok:  # pragma: no cover - cv2 always encodes jpg/png
            raise ConfigError("image encoding failed", expected=f"a .{fmt} image", received="cv2.imencode False")
        name = f"{session.view_ids[k]}.{fmt}"
        atomic_write_bytes(out / name, buf.tobytes())
        log.debug("rendered %s", name)
        return name

    with ThreadPoolExecutor(max(1, int(workers))) as pool:
        names = list(pool.map(render_one, range(session.n_views)))

    values = [
        [round(float(v), 9) for v in pose_values_from_T(T, VENDOR_POSE_FORMAT)] for T in session.T_base_end_reported
    ]
    if isinstance(target, ChessboardSpec):
        lines = [",".join(f"{v:.9f}" for v in vals) for vals in values]
        atomic_write_text(out / "poses.txt", "\n".join(lines) + "\n")
        config = {
            "checkerboard_args": {"XX": int(target.cols), "YY": int(target.rows), "L": float(target.square_m)},
            "mode": mode,
        }
        atomic_write_text(out / "config.yaml", yaml.safe_dump(config, sort_keys=False))
    else:  # the vendor layout has no place for other targets: the native session file, same poses
        doc = {
            "handeye_session": 1,
            "mode": mode,
            "target": target.to_dict(),
            "pose_format": {"rotation": "euler"},
            "views": [{"id": vid, "image": names[k], "pose": values[k]} for k, vid in enumerate(session.view_ids)],
        }
        if getattr(target, "pose_ambiguous", False):
            # four corners a view cannot calibrate a camera: a single-marker session states its intrinsics, as a
            # user of one tag does (the camera's factory values)
            doc["intrinsics"] = intrinsics_header(intrinsics, use="fixed")
        atomic_write_text(out / "session.yaml", yaml.safe_dump(doc, sort_keys=False))

    mount = mounting(mode)
    views = {}
    for k, vid in enumerate(session.view_ids):
        views[vid] = {
            "image": names[k],
            "T_base_end_true": session.T_base_end_true[k].tolist(),
            "T_base_end_reported": session.T_base_end_reported[k].tolist(),
            "T_cam_board_true": T_cam_board[k].tolist(),
            "hidden": vid in session.hidden_view_ids,
            "outlier": vid in session.outlier_view_ids,
        }
        if session.joints_encoder is not None:
            assert session.joints_true is not None, "the simulator records both"
            views[vid]["joints_encoder"] = session.joints_encoder[k].tolist()
            views[vid]["joints_true"] = session.joints_true[k].tolist()
    truth = {
        "handeye_synthetic_ground_truth": 1,
        "mode": mode,
        "frames": (
            "T_a_b maps points of frame b into frame a (p_a = T_a_b @ p_b), metres; cam is the optical "
            "frame (x right, y down, z forward); T_cam_board_i = inv(" + mount.x_name + ") . M_i . " + mount.board_name
        ),
        mount.x_name: session.T_x_true.tolist(),
        mount.board_name: session.T_board_true.tolist(),
        "target": target.to_dict(),
        "intrinsics": intrinsics.to_dict(),
        "views": views,
        "hidden_view_ids": list(session.hidden_view_ids),
        "outlier_view_ids": list(session.outlier_view_ids),
        "noise": {
            "image_noise_grey_levels": float(image_noise),
            "blur_sigma_px": float(blur_sigma_px),
            "gamma": float(gamma),
            "robot_noise_mm": float(session.robot_noise[0]),
            "robot_noise_deg": float(session.robot_noise[1]),
            "robot_noise_convention": (
                "T_base_end_reported = T_base_end_true @ dT, dT in the end frame: "
                "per-axis Gaussian rotation vector (deg) and translation (mm)"
            ),
            "outlier_trans_mm": list(view_options.get("outlier_trans_mm", (5.0, 30.0))),
            "outlier_rot_deg": list(view_options.get("outlier_rot_deg", (2.0, 10.0))),
            "render_supersample": int(supersample),
            "jpeg_quality": int(jpeg_quality) if fmt == "jpg" else None,
        },
        "robot_error": session.robot_model if session.robot_model is not None else {"model": session.robot_error},
        "seed": int(seed),
        "provenance": provenance(extra={"generator": "handeye.sim.vendor.write_vendor_session"}),
    }
    atomic_write_text(out / "ground_truth.json", to_json(truth) + "\n")
    log.info("wrote synthetic %s session with %d views to %s", mode, session.n_views, out)
    return out
