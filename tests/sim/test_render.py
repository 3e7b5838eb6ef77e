"""handeye.sim.render with a lens model that folds over inside the image (a fit from bunched corners).

Such intrinsics are what a poor calibration writes; the simulator renders through them (the part of the
image past the fold sees nothing) and the planner keeps boards on the side where the model holds.
"""

import numpy as np

from handeye.camera import FOLD_SHARE, Intrinsics, pixels_from_cam_points, radial_fold
from handeye.collect.visibility import board_in_image, image_normalized_extent
from handeye.frames import se3_exp
from handeye.sim import render
from handeye.targets import ChessboardSpec

#: 1280x720 at f 910 with k3 -1.67: the radial model rises to r_d 0.586, the image corners need 0.81
FOLDED = Intrinsics(910.37, 909.68, 642.63, 361.22, (0.0958, -0.0827, 0.00098, 0.00074, -1.6705), 1280, 720)


def test_the_fold_is_where_the_radial_model_stops_rising():
    rd_fold, r, rd = radial_fold(FOLDED.dist)
    k1, k2, _, _, k3 = FOLDED.dist
    slope = lambda x: 1 + 3 * k1 * x**2 + 5 * k2 * x**4 + 7 * k3 * x**6  # noqa: E731
    assert abs(slope(r[-1])) < 1e-3 and np.all(np.diff(rd) > 0)
    assert 0.5 < rd_fold < np.hypot(640 / 910, 360 / 910)  # inside the image
    assert radial_fold((0.1, -0.05, 0.0, 0.0, 0.01))[0] == np.inf  # an ordinary lens does not fold


def test_a_folded_lens_renders_the_board_where_it_sees_and_nothing_past_the_fold():
    grid = render.undistorted_sample_grid(FOLDED, supersample=1)
    sees = np.isfinite(grid[..., 0])
    assert sees[360, 640] and not sees[0, 0] and not sees[719, 1279]  # the centre sees, the corners not
    xy = grid[sees].astype(float)
    uv = pixels_from_cam_points(FOLDED.as_vector(), np.c_[xy, np.ones(len(xy))], jacobians=False)[0]
    vv, uu = np.nonzero(sees)
    assert np.max(np.abs(uv - np.c_[uu, vv])) < 1e-3  # where it sees, the grid is the model's inverse
    target = ChessboardSpec(cols=9, rows=6, square_m=0.03)
    T = se3_exp(np.r_[0.0, 0.0, 0.0, -0.13, -0.09, 0.8])  # board in the middle of the view
    img = render.render_view(target, FOLDED, T, supersample=1, background=128.0)
    assert img.shape == (720, 1280) and np.all(img[~sees] == 128)  # past the fold: the background alone
    assert img[sees].min() < 60 and img[sees].max() > 200  # the board's black and white squares


def test_the_planner_keeps_boards_inside_the_fold():
    ext = image_normalized_extent(FOLDED)
    rd_fold, r, rd = radial_fold(FOLDED.dist)
    assert np.sqrt(ext["r2_max"]) <= np.interp(FOLD_SHARE * rd_fold, rd, r) + 1e-9
    target = ChessboardSpec(cols=9, rows=6, square_m=0.03)
    centre = se3_exp(np.r_[0.0, 0.0, 0.0, -0.13, -0.09, 0.8])
    corner = se3_exp(np.r_[0.0, 0.0, 0.0, 0.25, 0.12, 0.8])  # towards the image corner, past the fold
    assert board_in_image(target, FOLDED, centre) and not board_in_image(target, FOLDED, corner)


def test_a_lens_that_folds_only_outside_the_image_sees_everywhere():
    barrel = Intrinsics(910.0, 910.0, 320.0, 180.0, (-0.3, 0.0, 0.0, 0.0, 0.0), 640, 360)
    assert np.isfinite(radial_fold(barrel.dist)[0])  # it folds at r_d 0.70, the image corners are at 0.40
    grid = render.undistorted_sample_grid(barrel, supersample=1)
    assert np.all(np.isfinite(grid)) and render.roundtrip_error_px(barrel, supersample=1, stride=7) < 1e-3
