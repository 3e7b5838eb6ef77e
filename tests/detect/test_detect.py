"""Detection on rendered images: corner accuracy, the one dispatcher, failed views with their reason,
the image measures taken during detection (blur, exposure, thumbnail) and the corner order of
asymmetric boards."""

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from handeye.camera import pixels_from_board_points
from handeye.detect import (
    board_size_verdict,
    detect_gray,
    detect_image,
    detect_views,
    read_gray,
    size_survey,
    visible_grid_sizes,
)
from handeye.detect.chessboard import detect_chessboard, normalize_chessboard_order, order_cue
from handeye.detect.options import default_options
from handeye.detect.quality import (
    board_mask,
    edge_profiles,
    image_exposure,
    neighbour_pairs,
    thumbnail_jpeg,
    view_blur,
    view_exposure,
)
from handeye.errors import ConfigError, InputError
from handeye.records import Detection, DetectionFailure
from handeye.sim.corners import make_corner_session
from handeye.sim.render import render_view
from handeye.sim.scenarios import default_intrinsics
from handeye.targets import CharucoSpec, ChessboardSpec

INTR = default_intrinsics(640, 480)


@pytest.fixture(scope="module")
def views():
    cs = make_corner_session(mode="eye_in_hand", n_views=4, seed=6, noise_px=0.0, intrinsics=INTR)
    return cs, [render_view(cs.target, INTR, T, supersample=3) for T in cs.T_cam_board_true]


def _rms(a, b):
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))


def test_rendered_corners_are_found_to_about_a_tenth_of_a_pixel(views):
    cs, imgs = views
    for T, img in zip(cs.T_cam_board_true, imgs, strict=False):
        ids, pts = detect_chessboard(img, cs.target)
        truth = pixels_from_board_points(T, cs.target.object_points()[ids], INTR)
        # measured 0.04-0.10 px RMS on 640x480 renders (cornerSubPix on anti-aliased edges)
        assert _rms(pts, truth) < 0.15


def test_one_dispatcher_for_every_target_kind(views):
    cs, imgs = views
    ids, pts = detect_gray(imgs[0], cs.target)
    assert np.array_equal(ids, np.arange(cs.target.n_corners))
    assert _rms(pts, pixels_from_board_points(cs.T_cam_board_true[0], cs.target.object_points(), INTR)) < 0.15
    # ChArUco goes to the ChArUco detector: ids from the markers, corners at their true pixels (sharp renders
    # with about 4 px between a square's corner and its marker: 0.11-0.16 px RMS per view, 0.13 over the four)
    ch = CharucoSpec(7, 5, 0.04, 0.03)
    errors = []
    for T in cs.T_cam_board_true:
        ids, pts = detect_gray(render_view(ch, INTR, T, supersample=3), ch)
        assert len(ids) >= 0.8 * ch.n_corners and np.all(np.diff(ids) > 0)
        errors.append(pts - pixels_from_board_points(T, ch.object_points()[ids], INTR))
    assert _rms(np.concatenate(errors), 0.0) < 0.15
    # a view with fewer corners than asked for is a reason, not a detection
    out = detect_gray(imgs[0], cs.target, min_corners=cs.target.n_corners + 1)
    assert out == f"only {cs.target.n_corners} corners detected (need at least {cs.target.n_corners + 1})"
    with pytest.raises(ConfigError, match="no detector"):
        detect_gray(imgs[0], object())


def test_board_numbered_from_the_other_end_is_turned_back(views):
    cs, imgs = views
    dets = {}
    for k, img in enumerate(imgs):
        ids, pts = detect_chessboard(img, cs.target)
        if k == 2:
            pts = pts[::-1].copy()  # what OpenCV sometimes returns for an 11x8 board
        dets[str(k)] = Detection(
            str(k), ids, pts, (640, 480), order_cue=order_cue(img, pts, cs.target.cols, cs.target.rows)
        )
    assert np.sign(dets["2"].order_cue) != np.sign(dets["0"].order_cue)
    fixed = normalize_chessboard_order(dets, cs.target)
    for k, T in enumerate(cs.T_cam_board_true):
        truth = pixels_from_board_points(T, cs.target.object_points(), INTR)
        assert np.max(np.abs(fixed[str(k)].image_points - truth)) < 0.5


def test_symmetric_boards_are_left_to_the_motion_check():
    sym = ChessboardSpec(9, 7, 0.03)
    d = {
        "1": Detection("1", np.arange(63), np.zeros((63, 2)), (640, 480), order_cue=-50.0),
        "2": Detection("2", np.arange(63), np.ones((63, 2)), (640, 480), order_cue=50.0),
        "3": Detection("3", np.arange(63), np.ones((63, 2)), (640, 480), order_cue=60.0),
    }
    assert normalize_chessboard_order(d, sym) is d


def test_detect_views_keeps_ids_reasons_and_measures(tmp_path, views):
    cs, imgs = views
    items = []
    for k, img in enumerate(imgs):
        p = tmp_path / f"{k + 1}.png"
        cv2.imwrite(str(p), img if k != 1 else np.full_like(img, 128))
        items.append((str(k + 1), p))
    res = detect_views(items, cs.target)
    fail = res["2"]
    assert isinstance(fail, DetectionFailure) and fail.view_id == "2"
    assert fail.reason == "chessboard 11x8 not found" and fail.image_size == (640, 480)
    # a uniform grey image: every pixel 128, none saturated
    assert fail.exposure == {"saturated_share": 0.0, "p5": 128.0, "p95": 128.0}
    thumb = cv2.imdecode(np.frombuffer(fail.thumbnail_jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert thumb.shape == (180, 240) and abs(float(thumb.mean()) - 128) < 1.0
    for v in ("1", "3", "4"):
        d = res[v]
        assert isinstance(d, Detection) and d.view_id == v and d.image_size == (640, 480)
        gray = read_gray(items[int(v) - 1][1])
        # the measures equal what the measuring functions give on the same image and corners
        assert d.exposure == view_exposure(gray, d.image_points)
        assert d.blur == view_blur(gray, d.image_points, d.corner_ids, cs.target.object_points(), cs.target.square_m)
        assert d.thumbnail_jpeg == thumbnail_jpeg(gray)
    (tmp_path / "5.png").write_bytes(b"garbage")
    with pytest.raises(InputError, match="5.png"):
        detect_views(items + [("5", tmp_path / "5.png")], cs.target)


def test_images_of_different_sizes_are_refused(tmp_path, views):
    cs, imgs = views
    cv2.imwrite(str(tmp_path / "1.png"), imgs[0])
    cv2.imwrite(str(tmp_path / "2.png"), cv2.resize(imgs[1], (320, 240)))
    with pytest.raises(InputError, match=r"view 2: image is 320x240, the other 1 views. are"):
        detect_views([("1", tmp_path / "1.png"), ("2", tmp_path / "2.png")], cs.target)


def test_jpeg_is_read_as_its_luma_like_the_colour_image(tmp_path, views):
    cs, imgs = views
    rng = np.random.default_rng(3)
    bgr = cv2.cvtColor(imgs[0], cv2.COLOR_GRAY2BGR).astype(np.int16)
    bgr[..., 0] += rng.integers(-40, 40, bgr.shape[:2], dtype=np.int16)  # a colour cast that varies per pixel
    bgr = np.clip(bgr, 0, 255).astype(np.uint8)
    p = tmp_path / "c.jpg"
    cv2.imwrite(str(p), bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    reference = cv2.cvtColor(cv2.imread(str(p), cv2.IMREAD_COLOR), cv2.COLOR_BGR2GRAY)
    g = read_gray(p)
    # libjpeg's luma vs. BT.601 grey of the decoded colours: the same weights, rounding differs by 1-2 levels
    assert g.shape == reference.shape and np.abs(g.astype(int) - reference).max() <= 2
    p16 = tmp_path / "deep.png"
    cv2.imwrite(str(p16), (imgs[0].astype(np.uint16) * 64 + 1000))
    g16 = read_gray(p16)  # 16-bit images are scaled to their own range
    assert g16.dtype == np.uint8 and g16.min() == 0 and g16.max() == 255


# ------------------------------------------------------------------------------ image measures
def test_edge_width_measures_the_rendered_blur(views):
    """The blur estimate against the Gaussian blur the renderer applied (sharp width removed)."""
    cs, _ = views
    T = cs.T_cam_board_true[0]
    obj = cs.target.object_points()
    truth = pixels_from_board_points(T, obj, INTR)
    ids = np.arange(len(obj))
    for sigma in (1.0, 2.0):
        img = render_view(cs.target, INTR, T, supersample=3, blur_sigma_px=sigma)
        b = view_blur(img, truth, ids, obj, cs.target.square_m)
        # measured within 0.03 px at 1 and 2 px on these views (profiles span +-0.33 square, ~3 sigma);
        # wider blurs are truncated by the profile (-0.2 px at 3 px) and are not asked for here
        assert abs(b["blur_sigma_px"] - sigma) < 0.05, b
        assert b["n_edges"] == 157  # 10 x 8 edges along x + 11 x 7 along y
    sharp = view_blur(render_view(cs.target, INTR, T, supersample=3), truth, ids, obj, cs.target.square_m)
    # a sharp render is as wide as the sharp-image width in configs/detection.yaml (measured 0.57-0.60 px)
    assert abs(sharp["edge_sigma_px"] - default_options().sharp_edge_sigma_px) < 0.1


def test_neighbour_pairs_on_a_partial_board():
    spec = ChessboardSpec(4, 3, 0.02)
    obj = spec.object_points()
    ids = np.array([0, 1, 2, 5, 6, 11])  # row 0: 0 1 2; row 1: 5 6; row 2: 11
    a, b = neighbour_pairs(obj, ids, spec.square_m)
    pairs = {(int(ids[i]), int(ids[j])) for i, j in zip(a, b, strict=False)}
    assert pairs == {(0, 1), (1, 2), (1, 5), (2, 6), (5, 6)}


def test_edge_profiles_are_bilinear_samples_with_the_border_repeated():
    rng = np.random.default_rng(1)
    g = rng.integers(0, 256, (40, 60)).astype(np.uint8)
    p0 = rng.uniform(-6, 66, (50, 2))
    p1 = p0 + rng.normal(0, 5, (50, 2))
    prof = edge_profiles(g, p0, p1, half_width=4.0)
    m, e = 0.5 * (p0 + p1), p1 - p0
    n = np.stack([-e[:, 1], e[:, 0]], 1) / np.linalg.norm(e, axis=1, keepdims=True)
    s = np.arange(-4.0, 4.0 + 1e-9, 0.25)
    pts = m[:, None] + s[None, :, None] * n[:, None]
    ref = map_coordinates(g.astype(float), [pts[..., 1].ravel(), pts[..., 0].ravel()], order=1, mode="nearest")
    assert np.abs(prof - ref.reshape(prof.shape)).max() < 1e-9


def test_exposure_is_the_share_and_percentiles_of_the_board_pixels():
    rng = np.random.default_rng(2)
    g = rng.integers(0, 256, (120, 160)).astype(np.uint8)
    g[40:60, 50:90] = 255
    pts = np.array([[30.3, 20.2], [140.8, 35.1], [120.4, 100.9], [20.1, 90.5]])
    v = g[board_mask(g.shape, pts)]
    want = {
        "saturated_share": float(np.mean(v >= default_options().saturated_grey)),
        "p5": float(np.percentile(v, 5)),
        "p95": float(np.percentile(v, 95)),
    }
    got = view_exposure(g, pts)
    assert got == pytest.approx(want, abs=1e-12) and got["saturated_share"] > 0.07
    whole = image_exposure(g)
    assert whole == pytest.approx(
        {
            "saturated_share": float(np.mean(g >= 250)),
            "p5": float(np.percentile(g, 5)),
            "p95": float(np.percentile(g, 95)),
        },
        abs=1e-12,
    )
    off = view_exposure(g, np.array([[-50.0, -50.0], [-10.0, -50.0], [-30.0, -10.0]]))  # hull outside the image
    assert all(np.isnan(x) for x in off.values())


def test_detect_image_on_a_rendered_1280x720_jpeg(tmp_path, views):
    cs, _ = views
    intr = default_intrinsics(1280, 720)
    T = cs.T_cam_board_true[1]
    p = tmp_path / "1.jpg"
    cv2.imwrite(str(p), render_view(cs.target, intr, T, supersample=2), [cv2.IMWRITE_JPEG_QUALITY, 95])
    d = detect_image("1", p, cs.target)
    assert isinstance(d, Detection) and d.image_size == (1280, 720)
    # half-size search, full-size sub-pixel refinement: as accurate as at 640x480
    assert _rms(d.image_points, pixels_from_board_points(T, cs.target.object_points(), intr)) < 0.15
    thumb = cv2.imdecode(np.frombuffer(d.thumbnail_jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert thumb.shape == (135, 240)
    # rendered without blur: the edges are as wide as a sharp image's, and nothing is saturated
    assert d.blur["blur_sigma_px"] < 0.5 and d.exposure["saturated_share"] == 0.0


def test_detection_settings_name_a_missing_or_unknown_key():
    from handeye.config import load_preset
    from handeye.detect.options import DetectionOptions

    cfg = load_preset("detection")["detection"]
    assert DetectionOptions.from_config(cfg) == default_options()
    with pytest.raises(ConfigError, match="min_corners"):
        DetectionOptions.from_config({k: v for k, v in cfg.items() if k != "min_corners"})
    with pytest.raises(ConfigError, match="blob_colour"):
        DetectionOptions.from_config(dict(cfg, circle_blobs=dict(cfg["circle_blobs"], blob_colour=0)))


# --- board size: which sizes the images show when the stated one is not found


def test_visible_grid_sizes_counts_the_inner_corners_whatever_size_is_stated(views):
    cs, imgs = views
    for img in imgs:
        assert visible_grid_sizes(img) == ((11, 8),)  # the rendered board: 11 x 8 inner corners
    assert visible_grid_sizes(np.full_like(imgs[0], 128)) == ()
    # turned a quarter: the same size (a detector cannot tell the board's orientation)
    assert visible_grid_sizes(np.ascontiguousarray(np.rot90(imgs[0]))) == ((11, 8),)


def test_a_3x3_grid_the_search_finds_in_a_background_is_no_board_size(tmp_path):
    """Views without the board (a blurred textured background): the size search finds its own 3x3 seed there and
    no more, which a checker-like texture gives as well; it is not a board size to name."""
    import cv2

    from handeye.detect.board_size import SEED
    from handeye.sim.vendor import write_vendor_session

    out = write_vendor_session(tmp_path / "s", n_views=3, seed=12, hidden_views=["1", "2"])
    for k in (1, 2):
        gray = read_gray(out / f"{k}.jpg")
        small = cv2.resize(gray, (640, 360), interpolation=cv2.INTER_AREA)
        flags = cv2.CALIB_CB_LARGER | cv2.CALIB_CB_NORMALIZE_IMAGE
        found, _, meta = cv2.findChessboardCornersSBWithMeta(small, SEED, flags=flags)
        assert found and meta.shape == SEED  # the detector's false grid
        assert visible_grid_sizes(gray, max_side_px=640, full_size_retry=True) == ()
    assert visible_grid_sizes(read_gray(out / "3.jpg"), max_side_px=640) == ((11, 8),)


def test_board_size_verdict_needs_the_stated_size_absent_and_another_in_most_views():
    three = {"1": ((11, 8),), "2": ((11, 8),), "3": ((11, 8),)}
    assert board_size_verdict((9, 6), three, n_searched=3) == (11, 8)
    assert board_size_verdict((6, 9), {"1": ((11, 8),), "2": (), "3": ((11, 8),)}, n_searched=3) == (11, 8)
    assert board_size_verdict((9, 6), {"1": ((11, 8),), "2": ((11, 5),), "3": ()}, n_searched=3) is None
    assert board_size_verdict((9, 6), {"1": (), "2": (), "3": ()}, n_searched=3) is None
    # another size is named only when most searched images show it: 3 of 10 (the stated board found in
    # the other 7) never, 5 of 10 neither (not most), 6 of 10 yes
    assert board_size_verdict((11, 9), dict.fromkeys("123", ((10, 9),)), n_searched=10) is None
    assert board_size_verdict((11, 9), dict.fromkeys("12345", ((10, 9),)), n_searched=10) is None
    assert board_size_verdict((11, 9), dict.fromkeys("123456", ((10, 9),)), n_searched=10) == (10, 9)
    # the stated size seen by the survey in a failed view never counts as another size
    assert board_size_verdict((9, 6), {**three, "4": ((9, 6),)}, n_searched=4) == (11, 8)  # 3 of 4
    assert board_size_verdict((9, 6), {**three, "4": ((9, 6),)}, n_searched=6) is None  # 3 of 6
    assert board_size_verdict((9, 6), three, n_searched=0) is None


def _write(tmp_path, imgs):
    items = []
    for k, img in enumerate(imgs):
        p = tmp_path / f"{k + 1}.png"
        cv2.imwrite(str(p), img)
        items.append((str(k + 1), p))
    return items


def test_a_wrong_board_size_is_searched_in_every_view_and_names_the_size_seen(tmp_path, views):
    cs, imgs = views
    items = _write(tmp_path, imgs + imgs[:2])  # 6 views of an 11 x 8 board
    res = detect_views(items, ChessboardSpec(9, 6, 0.03))
    assert list(res) == [v for v, _ in items] and all(isinstance(d, DetectionFailure) for d in res.values())
    for d in res.values():  # every image searched, each recording the size it shows
        assert d.seen_sizes == ((11, 8),)
        assert d.reason == "chessboard 9x6 not found; the detector sees 11x8 inner corners"
        assert d.thumbnail_jpeg and d.image_size == (640, 480)
    survey = size_survey(res, (9, 6))
    assert survey.likely_size == (11, 8) and survey.counts == {(11, 8): 6}
    assert survey.text() == "no 9x6 chessboard in 6 of 6 images; 11x8 inner corners seen in 6 of 6"
    assert "checkerboard_args XX: 11, YY: 8" in survey.fix() and "not 9x6" in survey.fix()
    # the stated size is found: no survey, every view detected
    res = detect_views(items, cs.target)
    assert all(isinstance(d, Detection) for d in res.values()) and size_survey(res, (11, 8)) is None


def test_a_wrong_board_size_is_refused_with_the_size_the_images_show(tmp_path, views):
    from handeye.pipeline import observe

    _, imgs = views
    obs = observe(target=ChessboardSpec(12, 8, 0.03), items=_write(tmp_path, imgs))
    assert obs.error.code == "target_not_found" and obs.error.exit_code == 3
    assert "found in only 0 of 4 images: no 12x8 chessboard in 4 of 4 images; 11x8 inner corners seen in 4 of 4" in (
        obs.error.what
    )
    assert "the board has 11x8 inner corners, not 12x8" in obs.error.hint


def test_when_the_first_views_show_no_other_size_every_view_is_searched(tmp_path, views):
    cs, imgs = views
    blank = np.full_like(imgs[0], 128)
    res = detect_views(_write(tmp_path, [blank, blank] + imgs), cs.target)
    assert [isinstance(d, Detection) for d in res.values()] == [False, False, True, True, True, True]
    assert res["1"].reason == "chessboard 11x8 not found"


def test_sizes_are_named_when_most_images_show_another_size(tmp_path, views):
    _, imgs = views
    blank = np.full_like(imgs[0], 128)
    res = detect_views(_write(tmp_path, [blank, blank] + imgs[:3]), ChessboardSpec(9, 6, 0.03))
    assert all(isinstance(d, DetectionFailure) for d in res.values())
    survey = size_survey(res, (9, 6))
    assert len(survey.seen) == 5 and survey.counts == {(11, 8): 3} and survey.likely_size == (11, 8)  # 3 of 5
    (tmp_path / "more").mkdir()
    res = detect_views(_write(tmp_path / "more", [blank] * 3 + imgs[:3]), ChessboardSpec(9, 6, 0.03))
    assert size_survey(res, (9, 6)).likely_size is None  # 3 of 6: not most


# --- corners right the first time: full-size refinement, the geometric check, bounded detection

INTR_HD = default_intrinsics(1280, 720)


@pytest.fixture(scope="module")
def hd_views():
    """(spec, image, true pixels of every corner): rendered 1280x720 views of the default board and of a
    board of few large squares (the low-texture case)."""
    out = []
    for spec in (ChessboardSpec(11, 8, 0.03), ChessboardSpec(5, 4, 0.06)):
        cs = make_corner_session(n_views=2, seed=3, noise_px=0.0, intrinsics=INTR_HD, target=spec)
        for T in cs.T_cam_board_true:
            out.append(
                (
                    spec,
                    render_view(spec, INTR_HD, T, supersample=4),
                    pixels_from_board_points(T, spec.object_points(), INTR_HD),
                )
            )
    return out


def _err_px(pts, truth):
    """Distance of each corner from the truth, in the board's numbering or the reversed one (the detector
    may number a board from either end; detect_views settles that later)."""
    return min((np.linalg.norm(p - truth, axis=1) for p in (pts, pts[::-1])), key=np.max)


def test_corners_at_1280x720_lie_within_about_a_twentieth_of_a_pixel_of_the_truth(hd_views):
    errs = []
    for spec, img, truth in hd_views:
        ids, pts = detect_chessboard(img, spec)
        assert np.array_equal(ids, np.arange(spec.n_corners))
        errs.append(_err_px(pts, truth))
    err = np.concatenate(errs)
    # noiseless renders: what is left is the symmetry fit on edges anti-aliased with 4x4 samples per pixel
    # (measured 0.016 px RMS, 0.06 px max on these four views; benchmarks/bench_detect.py prints 20 views
    # of each board); the bound is the one corners must meet (0.05 px RMS, no corner over 0.5 px)
    assert np.sqrt(np.mean(err**2)) < 0.05 and err.max() < 0.5


def test_coarse_corners_off_by_a_third_of_a_square_are_refined_back(hd_views, monkeypatch):
    import handeye.detect.chessboard as chessboard

    spec, img, truth = hd_views[0]
    wrong = truth.copy()
    wrong[[14, 15, 40]] += [[12.0, 0.0], [0.0, -10.0], [-8.0, 9.0]]  # as seen from a half-size search
    monkeypatch.setattr(chessboard, "find_chessboard_fast", lambda *a, **k: wrong)
    ids, pts = detect_chessboard(img, spec)
    # the windows come from the square size (not from the wrong spacing), the wrong corners restart
    # from the board homography: all back at the truth
    assert _err_px(pts, truth).max() < 0.3


def test_the_geometric_check_names_the_corner_off_its_neighbours(hd_views):
    from handeye.detect.geometry import check_corners

    spec, _, truth = hd_views[0]
    board_xy, o = spec.object_points()[:, :2], default_options()
    good = check_corners(board_xy, truth, o)
    # true corners: only the lens distortion across 5x5 corners is left (0.28 px at most, measured)
    assert good.passed and np.nanmax(good.residual_px) < 0.5
    bad = truth.copy()
    bad[30] += [4.0, -2.0]
    check = check_corners(board_xy, bad, o)
    assert not check.passed and check.worst == 30
    assert abs(check.residual_px[30] - np.hypot(4.0, 2.0)) < 0.5
    assert check.text().startswith("corner 30 lies 4.") and "from where its neighbours put it (limit" in check.text()
    # too few neighbours (a line of corners) is not checked rather than failed
    line = check_corners(board_xy[:11], bad[:11], o)
    assert line.passed and np.all(np.isnan(line.residual_px))


def test_the_geometric_check_passes_the_true_corners_of_a_strongly_distorted_wide_angle_view():
    """1920x1080 at f = 1078 px (83 deg across), k1 = -0.35, an 8x6 board of 35 mm squares at 0.4 m near the
    image's edge (squares of 85 px): distortion bends each 5x5 neighbourhood by pixels. The check's bend term
    takes that out; the homography alone put corner 16 4.9 px off, over its 4.6 px limit."""
    from handeye.detect.geometry import check_corners

    K = np.array([[1078.13, 0.0, 975.73], [0.0, 1075.45, 531.12], [0.0, 0.0, 1.0]])
    dist = np.array([-0.3529, 0.1205, 0.00064, 0.00084, -0.00061])
    obj = ChessboardSpec(8, 6, 0.035).object_points()
    truth = cv2.projectPoints(obj, np.array([0.1538, -0.4852, 0.0177]), np.array([-0.2303, -0.0814, 0.3305]), K, dist)[
        0
    ].reshape(-1, 2)
    check = check_corners(obj[:, :2], truth, default_options())
    assert check.passed and np.nanmax(check.residual_px / check.limit_px) < 0.6
    inner = [k for k in range(len(obj)) if 0 < k % 8 < 7 and 0 < k // 8 < 5]  # fitted with the bend
    assert np.nanmax(check.residual_px[inner]) < 1.5
    moved = truth.copy()
    moved[16] += [3.0, 4.0]  # a corner off by 5 px on the board's edge column is still named
    bad = check_corners(obj[:, :2], moved, default_options())
    assert not bad.passed and bad.worst == 16 and abs(bad.residual_px[16] - 5.0) < 1.0


def _corrupt_first_refinement(monkeypatch):
    import handeye.detect.chessboard as chessboard

    refine = chessboard.refine_chessboard
    after_accurate = [False]

    def corrupted(*a, **k):  # a detection's first refinement, not that of the accurate detector's corners
        pts = refine(*a, **k).copy()
        if not after_accurate[0]:
            pts[30] += [5.0, 0.0]
        after_accurate[0] = False
        return pts

    accurate = chessboard.cv2.findChessboardCornersSB

    def sb(*a, **k):
        after_accurate[0] = True
        return accurate(*a, **k)

    monkeypatch.setattr(chessboard.cv2, "findChessboardCornersSB", sb)

    monkeypatch.setattr(chessboard, "refine_chessboard", corrupted)
    return chessboard


def test_corners_that_fail_the_check_are_found_again_by_the_accurate_detector(hd_views, monkeypatch, caplog):
    spec, img, truth = hd_views[0]
    chessboard = _corrupt_first_refinement(monkeypatch)
    with caplog.at_level("INFO", logger="handeye.detect.chessboard"):
        ids, pts = detect_chessboard(img, spec)
    assert "fail the geometric check (corner 30 lies 5.0 px" in caplog.text
    # findChessboardCornersSB (EXHAUSTIVE | ACCURACY) on the full image: measured 0.02-0.1 px on these views
    assert _err_px(pts, truth).max() < 0.3
    # the accurate detector finds nothing either: the view is dropped with both reasons
    monkeypatch.setattr(chessboard.cv2, "findChessboardCornersSB", lambda *a, **k: (False, None))
    out = detect_chessboard(img, spec)
    assert out.startswith("chessboard corners fail the geometric check (corner 30 lies 5.0 px")
    assert out.endswith("and the accurate detector finds no board")


def test_a_spent_time_budget_drops_the_view_as_timed_out(tmp_path, hd_views, monkeypatch):
    from dataclasses import replace

    spec, img, _ = hd_views[0]
    tiny = replace(default_options(), time_budget_s=1e-9)
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full_like(img, 128))
    d = detect_image("1", blank, spec, options=tiny)
    # the half-size search ran; the full-size and SB searches were skipped
    assert isinstance(d, DetectionFailure) and d.reason.startswith("detection timed out: ")
    assert d.reason.endswith("(configs/detection.yaml time_budget_s), the full-size chessboard searches skipped")
    with_board = tmp_path / "board.png"
    cv2.imwrite(str(with_board), img)
    assert isinstance(detect_image("2", with_board, spec, options=tiny), Detection)  # found by the first search
    _corrupt_first_refinement(monkeypatch)
    d = detect_image("2", with_board, spec, options=tiny)
    assert d.reason.startswith("detection timed out: ")
    assert "the accurate search after the geometric check failed (corner 30 lies 5.0 px" in d.reason


def test_images_above_the_size_limit_are_searched_reduced_and_refined_at_full_size(hd_views, caplog):
    from dataclasses import replace

    spec, img, truth = hd_views[1]
    small_limit = replace(default_options(), search_max_megapixels=0.3)  # 1280x720 is 0.92 MP
    with caplog.at_level("INFO", logger="handeye.detect.geometry"):
        ids, pts = detect_chessboard(img, spec, options=small_limit)
    assert "image 1280x720 (0.9 MP) is above the 0.3 MP search limit: searched at 730x410" in caplog.text
    assert _err_px(pts, truth).max() < 0.3  # the full-size refinement, not the reduced copy, places them
    out = detect_chessboard(np.full_like(img, 128), spec, options=small_limit)
    assert out == "chessboard 11x8 not found (searched at 730x410: the image is above 0.3 MP)"


def test_steeply_tilted_charuco_corners_are_refined_in_the_board_frontal_frame():
    """Views tilted 55-65 deg at 0.35-0.5 m through a tone curve: the white band between a square's corner and
    its marker is about 4 px across its foreshortened side, and OpenCV's window in the image reached the marker
    (0.62 px RMS and a corner 2.7 px off over six such views, measured); in the board's frontal frame 0.05 px."""
    from handeye.sim.scenarios import default_intrinsics as intrinsics

    ch, intr = CharucoSpec(9, 7, 0.03, 0.022, "DICT_5X5_100"), intrinsics(1280, 720)
    s = make_corner_session(n_views=3, seed=7, noise_px=0.0, target=ch, tilt_deg=(55.0, 65.0), distance_m=(0.35, 0.5))
    errors = []
    for k in range(s.n_views):
        out = detect_gray(render_view(ch, intr, s.T_cam_board_true[k], blur_sigma_px=0.8, gamma=2.2), ch)
        assert not isinstance(out, str), out
        truth = dict(zip(s.corner_ids[k].tolist(), s.image_points[k], strict=True))
        errors.append(out[1] - np.array([truth[int(i)] for i in out[0]]))
    e = np.linalg.norm(np.concatenate(errors), axis=1)
    assert len(e) >= 0.9 * 3 * ch.n_corners, len(e)
    assert np.sqrt(np.mean(e**2)) < 0.1 and e.max() < 0.5, (np.sqrt(np.mean(e**2)), e.max())


def test_charuco_corners_off_their_neighbours_are_dropped_alone(views):
    from handeye.detect.charuco import off_grid_corners_removed

    cs, _ = views
    ch = CharucoSpec(9, 7, 0.04, 0.03)
    pts = pixels_from_board_points(cs.T_cam_board_true[0], ch.object_points(), INTR)
    assert off_grid_corners_removed(ch.object_points()[:, :2], pts, default_options()).all()
    pts[20] += [0.0, 6.0]
    keep = off_grid_corners_removed(ch.object_points()[:, :2], pts, default_options())
    assert np.flatnonzero(~keep).tolist() == [20]


def test_charuco_views_above_the_size_limit_are_searched_reduced_and_refined_at_full_size(views):
    from dataclasses import replace

    cs, _ = views
    ch = CharucoSpec(7, 5, 0.04, 0.03)
    T = cs.T_cam_board_true[0]
    img = render_view(ch, INTR, T, supersample=3)
    small_limit = replace(default_options(), search_max_megapixels_charuco_circles=0.2)  # 640x480 is 0.31 MP
    ids, pts = detect_gray(img, ch, options=small_limit)
    assert len(ids) >= 0.8 * ch.n_corners
    # the corners of the full-size search (test_one_dispatcher_for_every_target_kind: at their true pixels):
    # the full image's refinement starts from the copy's, a few hundredths of a px apart at most (0.023 measured)
    full_ids, full = detect_gray(img, ch)
    assert np.array_equal(ids, full_ids) and np.abs(pts - full).max() < 0.05
    out = detect_gray(np.full_like(img, 128), ch, options=small_limit)
    assert out == "ChArUco board not found (0 markers seen, searched at 516x387)"


# --- the second refinement stage: the centre of point symmetry, and corners the two stages disagree on


def _smooth_corner(size, c, normals, *, shading=(0.0, 0.0)):
    """A blurred checker corner at ``c`` (px) whose edges have the given unit normals (any angle between
    them), point-symmetric about ``c``, plus a linear shading (grey levels per px), float32 (H, W)."""
    y, x = np.mgrid[0 : size[0], 0 : size[1]].astype(float)
    d = np.stack([x - c[0], y - c[1]], axis=-1)
    s1, s2 = (np.tanh(d @ np.asarray(n, float) / 1.5) for n in normals)
    return (128.0 + 80.0 * s1 * s2 + shading[0] * (x - c[0]) + shading[1] * (y - c[1])).astype(np.float32)


def test_the_symmetry_fit_finds_a_skewed_corner_under_shading():
    from handeye.detect.saddle import shading_free, symmetric_corners

    c = np.array([20.37, 18.81])
    normals = [(1.0, 0.0), (np.sin(np.radians(35.0)), np.cos(np.radians(35.0)))]  # edges 55 deg apart
    start = c + [[0.8, -0.6]]
    for shading in ((0.0, 0.0), (1.5, -1.0)):
        img = _smooth_corner((40, 42), c, normals, shading=shading)
        pts, ok = symmetric_corners(shading_free(img, box_px=17), start, np.array([5]), iterations=6)
        # noiseless and smooth: only the bilinear sampling of a 1.5 px edge is left (measured 0.005 px)
        assert ok[0] and np.linalg.norm(pts[0] - c) < 0.02
    # the shading taken out is what makes it unbiased: on the shaded image itself the ramp pulls it off
    raw, _ = symmetric_corners(img, start, np.array([5]), iterations=6)
    assert np.linalg.norm(raw[0] - c) > 0.1
    # a window without a corner (a dark spot) holds no saddle: not ok
    y, x = np.mgrid[0:40, 0:42]
    spot = (128.0 - 80.0 * np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2) / 8.0)).astype(np.float32)
    _, ok = symmetric_corners(shading_free(spot, box_px=17), start, np.array([5]), iterations=6)
    assert not ok[0]


def test_the_second_stage_removes_the_aliasing_of_sharp_edges(hd_views, monkeypatch):
    import handeye.detect.chessboard as chessboard

    errs = {}
    for stages in ("both", "cornerSubPix on the smoothed image", "cornerSubPix only"):
        if stages != "both":  # the second stage left out: its corners are the first stage's
            monkeypatch.setattr(
                chessboard,
                "symmetric_corners",
                lambda image, pts, half, iterations: (pts.copy(), np.ones(len(pts), bool)),
            )
        if stages == "cornerSubPix only":  # ... and the image not smoothed either
            monkeypatch.setattr(
                chessboard,
                "final_corners",
                lambda gray, bxy, start, win, o, dropped=None: chessboard.refine_corners(gray, start, win, o),
            )
        e = [_err_px(detect_chessboard(img, spec)[1], truth) for spec, img, truth in hd_views]
        errs[stages] = np.concatenate(e)
    rms = {k: float(np.sqrt(np.mean(e**2))) for k, e in errs.items()}
    # 4x4 samples per pixel: cornerSubPix alone 0.043 px RMS on these views, on the smoothed image 0.023 px,
    # both stages 0.016 px (measured; benchmarks/bench_detect.py prints 20 views of each board)
    assert rms["both"] < 0.035 and errs["both"].max() < 0.2
    assert rms["cornerSubPix on the smoothed image"] < 0.7 * rms["cornerSubPix only"]
    assert rms["both"] < 0.8 * rms["cornerSubPix on the smoothed image"], rms


def test_a_corner_the_two_estimators_disagree_on_is_not_used(hd_views, caplog):
    spec, img, truth = hd_views[0]
    spot = img.copy()
    c = truth[30] + [2.0, 2.0]  # a reflection 3 px wide beside corner 30
    cv2.circle(spot, tuple(int(v) for v in np.round(c * 16)), 48, 255, -1, shift=4, lineType=cv2.LINE_AA)
    with caplog.at_level("INFO", logger="handeye.detect.chessboard"):
        ids, pts = detect_chessboard(spot, spec)
    assert 30 not in ids and len(ids) == spec.n_corners - 1
    assert "corner 30 not used: cornerSubPix and the symmetry fit put it" in caplog.text
    assert "configs/detection.yaml corner_disagreement_max_px" in caplog.text
    assert _err_px(pts, truth[ids]).max() < 0.2  # the others stay where they were


def test_a_corner_left_out_is_kept_with_its_reason_for_result_json(tmp_path, hd_views, caplog):
    from types import SimpleNamespace

    from handeye.detect import detect_image
    from handeye.results import dropped_corners

    spec, img, truth = hd_views[0]
    spot = img.copy()
    c = truth[30] + [2.0, 2.0]
    cv2.circle(spot, tuple(int(v) for v in np.round(c * 16)), 48, 255, -1, shift=4, lineType=cv2.LINE_AA)
    cv2.imwrite(str(tmp_path / "7.png"), spot)
    with caplog.at_level("INFO", logger="handeye.detect"):
        det = detect_image("7", tmp_path / "7.png", spec)
    assert [k for k, _ in det.dropped_corners] == [30] and 30 not in det.corner_ids
    said = [r.getMessage() for r in caplog.records if "not used" in r.getMessage()]
    assert len(said) == 1 and said[0].startswith("view 7: corner 30 not used: "), said  # which view, once
    assert "cornerSubPix and the symmetry fit put it" in det.dropped_corners[0][1]
    # numbered as the view's used corners: on a symmetric board seen turned by 180 degrees (orientation 1)
    # corner k is corner n - 1 - k
    n = spec.n_corners
    turns = SimpleNamespace(symmetries=lambda: [np.arange(n), np.arange(n)[::-1]])
    run = SimpleNamespace(
        detections={"7": det}, session=SimpleNamespace(target=turns), board_poses={"7": SimpleNamespace(orientation=1)}
    )
    assert dropped_corners(run, "7") == [{"corner_id": n - 1 - 30, "reason": det.dropped_corners[0][1]}]
    assert dropped_corners(run, "8") == []  # a view without detection


def test_a_view_missing_a_corner_keeps_its_order_cue_and_is_turned_back_whole(views):
    cs, imgs = views
    spec = cs.target
    ids, pts = detect_chessboard(imgs[0], spec)
    full = order_cue(imgs[0], pts, spec.cols, spec.rows)
    keep = np.setdiff1d(ids, [0, 40])  # corner 0 is one of the four around the first square
    assert abs(order_cue(imgs[0], pts[keep], spec.cols, spec.rows, keep) - full) < 1.0
    d = Detection("0", keep, pts[keep], (640, 480), order_cue=full)
    turned = Detection(
        "1", (spec.n_corners - 1 - keep)[::-1].copy(), pts[keep][::-1].copy(), (640, 480), order_cue=-full
    )
    fixed = normalize_chessboard_order({"0": d, "1": turned, "2": d}, spec)
    assert np.array_equal(fixed["1"].corner_ids, keep) and np.allclose(fixed["1"].image_points, pts[keep])


def test_an_exif_orientation_flag_is_not_applied(tmp_path):
    """A JPEG whose EXIF asks viewers to turn it 90 deg is read as the sensor stored it: turned, the camera frame
    and X came out turned by 90 deg (exit 0, no word). OpenCV applies the flag by default."""
    import struct

    import cv2

    from handeye.detect import read_gray

    img = np.zeros((60, 100), np.uint8)
    img[10:20, 10:30] = 255
    data = cv2.imencode(".jpg", img)[1].tobytes()
    tiff = b"MM\x00\x2a\x00\x00\x00\x08" + struct.pack(">H", 1) + struct.pack(">HHIHH", 0x0112, 3, 1, 6, 0)
    app1 = b"Exif\x00\x00" + tiff + struct.pack(">I", 0)  # orientation 6: turn 90 deg clockwise to view
    path = tmp_path / "turned.jpg"
    path.write_bytes(data[:2] + b"\xff\xe1" + struct.pack(">H", len(app1) + 2) + app1 + data[2:])
    assert cv2.imdecode(np.fromfile(str(path), np.uint8), cv2.IMREAD_GRAYSCALE).shape == (100, 60)  # OpenCV turns it
    got = read_gray(path)
    assert got.shape == (60, 100) and np.abs(got.astype(int) - img).max() < 40


def test_a_grid_whose_outer_line_is_no_chessboard_corners_is_not_the_board():
    """OpenCV can fit a 12x8 grid to an 11x8 board: its outer column on the board's edge (no saddles there, every
    such corner left out) and every other corner a column off its id. Such a grid is no detection of the stated
    board (a rendered 640x360 view did this; calibrate then used its corners under the wrong ids)."""
    from handeye.detect.chessboard import _edge_line, board_squares

    bxy = board_squares(ChessboardSpec(12, 8, 0.03))
    pts = np.c_[bxy * 20.0 + 50.0]
    assert _edge_line(bxy, pts) is None
    for axis, end in ((0, "min"), (0, "max"), (1, "min"), (1, "max")):
        lost = pts.copy()
        line = bxy[:, axis] == getattr(bxy[:, axis], end)()
        lost[line] = np.nan
        assert "outer " + ("column" if axis == 0 else "row") in _edge_line(bxy, lost)
        lost[np.flatnonzero(line)[0]] = pts[np.flatnonzero(line)[0]]  # one corner of the line kept: the board
        assert _edge_line(bxy, lost) is None
    inner = pts.copy()
    inner[bxy[:, 0] == 3] = np.nan  # a whole inner column lost (glare across it) is no sign of the edge
    assert _edge_line(bxy, inner) is None
