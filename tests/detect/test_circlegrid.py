"""Circle-grid targets: the spec's geometry and symmetries, parsing, and detection on drawn images."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from handeye.detect import detect_gray
from handeye.detect.circlegrid import detect_circlegrid
from handeye.errors import ConfigError
from handeye.session.target_spec import parse_target
from handeye.targets import CircleGridSpec

# drawn board: dot (c, r) at texture pixel (MARGIN + PITCH*c, MARGIN + PITCH*r); x right, y down = front view
PITCH, MARGIN, RADIUS = 36, 70, 9
# dot centres within this of the drawn ones (px): measured up to 0.088 px on these views, a systematic
# offset (a disk's blob centroid under perspective is not its projected centre), not noise
DOT_TOL_PX = 0.15


def _texture(cols: int, rows: int, *, origin_dot: bool, distractor: bool, moved: dict | None = None) -> np.ndarray:
    """``moved``: {(c, r): (dx, dy)} dots drawn that many texture px off the grid."""
    w, h = 2 * MARGIN + PITCH * (cols - 1), 2 * MARGIN + PITCH * (rows - 1)
    tex = np.full((h * 8, w * 8), 235, np.uint8)  # drawn 8x larger, then reduced: anti-aliased edges
    for r in range(rows):
        for c in range(cols):
            rad = 2 * RADIUS if (origin_dot and r == c == 0) else RADIUS
            dx, dy = (moved or {}).get((c, r), (0, 0))
            _disk(tex, MARGIN + PITCH * c + dx, MARGIN + PITCH * r + dy, rad)
    if distractor:  # a larger dark disk outside the grid, like the printed legend on the ROS-I board
        _disk(tex, w - 28, 28, 24)
    return cv2.resize(tex, (w, h), interpolation=cv2.INTER_AREA)


def _disk(tex8, x, y, radius):
    """Dark disk centred on reduced-image pixel (x, y) of a texture drawn 8x larger: reduced pixel i
    covers drawn pixels 8i..8i+7, centre 8i+3.5 (coordinates in half pixels, shift=1)."""
    cv2.circle(tex8, (16 * x + 7, 16 * y + 7), 16 * radius, 25, -1, shift=1)


def _view(cols=10, rows=10, *, origin_dot=True, distractor=True, moved=None):
    """(image, H, expected (n,2)): the board under a mild perspective; expected[r*cols+c] is dot (c, r)."""
    tex = _texture(cols, rows, origin_dot=origin_dot, distractor=distractor, moved=moved)
    h, w = tex.shape
    src = np.float32([[0, 0], [w, 0], [w, h], [0, h]])
    dst = np.float32([[150, 70], [520, 95], [560, 430], [110, 400]])
    H = cv2.getPerspectiveTransform(src, dst)
    img = cv2.warpPerspective(tex, H, (640, 480), flags=cv2.INTER_LINEAR, borderValue=60)
    r, c = np.divmod(np.arange(cols * rows), cols)
    tp = np.stack([MARGIN + PITCH * c, MARGIN + PITCH * r], axis=1).astype(float)
    # texture pixel centres sit at integer coordinates; warpPerspective maps pixel centres the same way
    exp = cv2.perspectiveTransform(tp.reshape(-1, 1, 2), H).reshape(-1, 2)
    return img, H, exp


def _cross(pts, cols, rows):
    g = pts.reshape(rows, cols, 2)
    ax = (g[:, 1:] - g[:, :-1]).mean(axis=(0, 1))
    ay = (g[1:] - g[:-1]).mean(axis=(0, 1))
    return ax[0] * ay[1] - ax[1] * ay[0]


# ------------------------------------------------------------------------------ spec
def test_object_points_layout():
    s = CircleGridSpec(4, 3, 0.02)
    P = s.object_points()
    assert P.shape == (12, 3) and s.n_corners == 12
    assert np.allclose(P[5], [0.02, 0.02, 0]) and np.allclose(P[11], [0.06, 0.04, 0])
    a = CircleGridSpec(4, 11, 0.01, asymmetric=True).object_points()
    assert np.allclose(a[4], [0.01, 0.01, 0]) and np.allclose(a[5], [0.03, 0.01, 0])  # row 1 staggered


@pytest.mark.parametrize(
    "spec, n_sym",
    [
        (CircleGridSpec(10, 10, 0.0254, origin_dot=True), 4),
        (CircleGridSpec(7, 5, 0.03), 2),
        (CircleGridSpec(4, 11, 0.02, asymmetric=True), 1),
        (CircleGridSpec(4, 10, 0.02, asymmetric=True), 2),
    ],
)
def test_symmetries_are_proper_in_plane_motions(spec, n_sym):
    P = spec.object_points()[:, :2]
    syms = spec.symmetries()
    assert len(syms) == n_sym and np.array_equal(syms[0], np.arange(spec.n_corners))
    assert len({tuple(p) for p in syms}) == n_sym, "symmetries must be distinct"
    for perm in syms:
        assert sorted(perm) == list(range(spec.n_corners)), "a symmetry is a permutation"
        # the relabelled points are the grid moved rigidly in its plane (a turn, never a mirror)
        A, B = P - P.mean(0), P[perm] - P[perm].mean(0)
        U, _, Vt = np.linalg.svd(B.T @ A)
        R = U @ Vt
        assert np.linalg.det(R) > 0, "a mirror ordering is not a symmetry (board seen from behind)"
        assert np.allclose(A @ R.T, B, atol=1e-12), "relabelled grid must be a rigid turn of the grid"


def test_symmetries_match_chessboard_order_for_square_grids():
    from handeye.targets import ChessboardSpec

    for a, b in zip(CircleGridSpec(6, 6, 0.02).symmetries(), ChessboardSpec(6, 6, 0.02).symmetries(), strict=False):
        assert np.array_equal(a, b)  # initial.board_poses._majority_frame relies on the order 0, 180, 90, 270 degrees


def test_parse_target_round_trip_and_errors():
    spec = CircleGridSpec(10, 10, 0.0254, origin_dot=True)
    assert parse_target(spec.to_dict(), path=Path("s.yaml")) == spec
    assert parse_target(
        {"type": "circlegrid", "grid": [4, 11], "spacing_m": 0.02, "asymmetric": True}, path=Path("s.yaml")
    ) == CircleGridSpec(4, 11, 0.02, asymmetric=True)
    with pytest.raises(ConfigError, match="grid"):
        parse_target({"type": "circlegrid", "grid": 10, "spacing_m": 0.02}, path=Path("s.yaml"))
    with pytest.raises(ConfigError, match="millimetres"):
        parse_target({"type": "circlegrid", "grid": [10, 10], "spacing_m": 25.4}, path=Path("s.yaml"))
    with pytest.raises(ConfigError, match="origin_dot"):
        parse_target(
            {"type": "circlegrid", "grid": [10, 10], "spacing_m": 0.02, "origin_dot": "yes"}, path=Path("s.yaml")
        )


# ------------------------------------------------------------------------------ detection
def test_detects_drawn_grid_with_origin_dot_despite_a_larger_distractor():
    img, _, exp = _view()
    ids, pts = detect_circlegrid(img, CircleGridSpec(10, 10, 0.0254, origin_dot=True))
    assert np.array_equal(ids, np.arange(100))
    err = np.linalg.norm(pts - exp, axis=1)
    assert err.max() < DOT_TOL_PX, f"dot centres off by up to {err.max():.2f} px"


@pytest.mark.parametrize("turn", [cv2.ROTATE_90_CLOCKWISE, cv2.ROTATE_180, cv2.ROTATE_90_COUNTERCLOCKWISE])
def test_origin_dot_fixes_the_order_in_turned_images(turn):
    img, _, exp = _view()
    h, w = img.shape
    turned = cv2.rotate(img, turn)
    x, y = exp[:, 0], exp[:, 1]
    exp_t = {
        cv2.ROTATE_90_CLOCKWISE: np.stack([h - 1 - y, x], 1),
        cv2.ROTATE_180: np.stack([w - 1 - x, h - 1 - y], 1),
        cv2.ROTATE_90_COUNTERCLOCKWISE: np.stack([y, w - 1 - x], 1),
    }[turn]
    _, pts = detect_circlegrid(turned, CircleGridSpec(10, 10, 0.0254, origin_dot=True))
    assert np.linalg.norm(pts - exp_t, axis=1).max() < DOT_TOL_PX


def test_mirrored_image_is_numbered_as_seen_from_the_front():
    img, _, exp = _view()
    w = img.shape[1]
    mirrored = cv2.flip(img, 1)  # what a detector sees when the board is seen "from behind"
    _, pts = detect_circlegrid(mirrored, CircleGridSpec(10, 10, 0.0254, origin_dot=True))
    assert _cross(pts, 10, 10) > 0, "ordering must have the handedness of a front view"
    exp_m = np.stack([w - 1 - exp[:, 0], exp[:, 1]], 1)
    assert np.linalg.norm(pts[0] - exp_m[0]) < DOT_TOL_PX, "id 0 must be the big dot"
    # front handedness from the big dot: the detected x axis runs along the drawn y axis
    assert (
        np.linalg.norm(pts.reshape(10, 10, 2) - exp_m.reshape(10, 10, 2).transpose(1, 0, 2), axis=2).max() < DOT_TOL_PX
    )


def test_plain_grid_order_is_a_turn_of_the_true_order():
    spec = CircleGridSpec(7, 5, 0.03)
    img, _, exp = _view(7, 5, origin_dot=False, distractor=False)
    for im, e in ((img, exp), (cv2.rotate(img, cv2.ROTATE_180), None)):
        ids, pts = detect_circlegrid(im, spec)
        assert _cross(pts, 7, 5) > 0
        if e is not None:
            # some symmetry maps the detected order onto the true one
            errs = [np.linalg.norm(pts[np.argsort(p)] - e, axis=1).max() for p in spec.symmetries()]
            assert min(errs) < DOT_TOL_PX, errs


def test_the_dispatcher_sends_circle_grids_to_the_circle_detector():
    img, _, exp = _view()
    spec = CircleGridSpec(10, 10, 0.0254, origin_dot=True)
    ids, pts = detect_gray(img, spec)
    assert np.array_equal(ids, np.arange(100)) and np.linalg.norm(pts - exp, axis=1).max() < DOT_TOL_PX
    assert detect_gray(img, CircleGridSpec(12, 9, 0.02)) == "circle grid 12x9 not found"


def test_reports_a_reason_when_the_grid_is_absent():
    img, _, _ = _view()
    out = detect_circlegrid(img, CircleGridSpec(12, 9, 0.02))
    assert isinstance(out, str) and "not found" in out


def test_a_grid_with_a_dot_off_its_place_fails_the_geometric_check():
    spec = CircleGridSpec(10, 10, 0.02, origin_dot=True)
    img, _, exp = _view()
    ids, pts = detect_circlegrid(img, spec)  # the regular grid passes
    assert np.max(np.linalg.norm(pts - exp[ids], axis=1)) < DOT_TOL_PX
    # dot (4, 5) drawn 6 px (a sixth of the pitch) off: still found as a grid, refused by the check
    img, _, _ = _view(moved={(4, 5): (6, 0)})
    out = detect_circlegrid(img, spec)
    assert isinstance(out, str) and out.startswith("circle grid dots fail the geometric check: dot ")
    assert "px from where its neighbours put it (limit " in out


def test_a_grid_in_an_image_above_the_size_limit_is_searched_on_a_reduced_copy():
    from dataclasses import replace

    from handeye.detect.options import default_options

    spec = CircleGridSpec(10, 10, 0.02, origin_dot=True)
    img, _, exp = _view()
    small_limit = replace(default_options(), search_max_megapixels_charuco_circles=0.2)  # 640x480 is 0.31 MP
    ids, pts = detect_circlegrid(img, spec, options=small_limit)
    # centres found on the 0.8x copy and scaled back: measured 0.079 px at most, 0.084 at full size
    assert np.array_equal(ids, np.arange(100)) and np.max(np.linalg.norm(pts - exp, axis=1)) < 0.2
    out = detect_circlegrid(np.full_like(img, 200), spec, options=small_limit)
    assert out == "circle grid 10x10 not found (searched at 516x387: the image is above 0.2 MP)"
