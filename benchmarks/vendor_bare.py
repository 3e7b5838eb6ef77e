"""The bare vendor script handeye replaces, as shipped with a RealSense D435 + RealMan arm kit.

Imports only numpy, yaml and cv2: finds the chessboard in every image, calibrates the camera, runs
calibrateHandEye (Tsai) and prints T_end_cam. No uncertainty, no checks. Kept as the reference of
``bench_vs_opencv.py``.

    python benchmarks/vendor_bare.py SESSION_FOLDER
"""

import sys
from pathlib import Path

import cv2
import numpy as np
import yaml


def euler_zyx(rx: float, ry: float, rz: float) -> np.ndarray:
    """R = Rz(rz) @ Ry(ry) @ Rx(rx), the vendor's convention."""
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def main(folder: Path) -> None:
    cfg = yaml.safe_load((folder / "config.yaml").read_text())["checkerboard_args"]
    cols, rows, square = int(cfg["XX"]), int(cfg["YY"]), float(cfg["L"])
    obj = np.zeros((cols * rows, 3), np.float32)
    obj[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square
    poses = [[float(x) for x in ln.split(",")] for ln in (folder / "poses.txt").read_text().split("\n") if ln.strip()]
    obj_pts, img_pts, R_g2b, t_g2b, size = [], [], [], [], None
    for k, pose in enumerate(poses, start=1):
        img = cv2.imread(str(folder / f"{k}.jpg"))
        if img is None:
            continue
        gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        size = gray.shape[::-1]
        ok, corners = cv2.findChessboardCorners(gray, (cols, rows), None)
        if not ok:
            continue
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
        corners = cv2.cornerSubPix(gray, corners, (11, 11), (-1, -1), criteria)
        obj_pts.append(obj)
        img_pts.append(corners)
        R_g2b.append(euler_zyx(*pose[3:6]))
        t_g2b.append(np.array(pose[:3]))
    _, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj_pts, img_pts, size, None, None)
    R_t2c = [cv2.Rodrigues(r)[0] for r in rvecs]
    R, t = cv2.calibrateHandEye(R_g2b, t_g2b, R_t2c, tvecs, method=cv2.CALIB_HAND_EYE_TSAI)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t.ravel()
    print(T)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
