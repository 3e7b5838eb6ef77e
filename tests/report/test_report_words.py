"""The report's words for what a result is: a pose-only session's noise, the offsets from the closed forms.

A pose-only session (target poses from a tracker) has no pixels: its noise section states the tracker's noise as
result.json holds it, with no pixel rows and no sentence about pixel noise. The "Where the result lies" table says
what its sigmas measure instead of calling every closed form a departure; a closed-form-only run's report does
not speak of a refined result or of a ratio it does not show.
"""

from __future__ import annotations

import html as html_lib
import json
import re
from pathlib import Path

import pytest

from handeye.pipeline import CalibrateOptions
from handeye.report import write_reports
from handeye.workflow import calibrate_session


def _reports(folder: Path, *, plots: bool = False) -> tuple[str, str]:
    """(report.md, the visible text of report.html) written from ``folder``."""
    write_reports(folder, strict=True, plots=plots)
    page = (folder / "report.html").read_text(encoding="utf-8")
    text = html_lib.unescape(re.sub(r"<[^>]+>", " ", page.split("<body>")[1]))
    return (folder / "report.md").read_text(encoding="utf-8"), " ".join(text.split())


def _between(text: str, start: str, end: str) -> str:
    assert start in text, start
    return text[text.index(start) : text.index(end, text.index(start))]


def _noise_section(page: str) -> str:
    """The noise section of report.md or of report.html's text, under either of its headings."""
    start = min(i for h in ("Tracker and robot noise", "Camera and noise model") if (i := page.find(h)) >= 0)
    return page[start : page.index("Provenance", start)]


@pytest.fixture(scope="module")
def pose_only(tmp_path_factory) -> Path:
    """A 12-view pose-only session with its tracker's noise stated (0.5 mm, 0.2 deg), calibrated."""
    from handeye.sim.poses import make_tracker_session

    root = tmp_path_factory.mktemp("words_pose_only")
    make_tracker_session(mode="eye_in_hand", n_views=12, seed=3).write(root / "session")
    calibrate_session(root / "session", out_dir=root / "result", report=False)
    return root / "result"


@pytest.fixture(scope="module")
def images(tmp_path_factory) -> dict:
    """An 8-view rendered eye-in-hand session calibrated refined (``refined``) and closed form only (``closed``)."""
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session

    root = tmp_path_factory.mktemp("words_images")
    session = write_vendor_session(
        root / "session", n_views=8, seed=3, intrinsics=default_intrinsics(400, 300), supersample=2, workers=1
    )
    calibrate_session(session, out_dir=root / "refined", report=False)
    calibrate_session(session, options=CalibrateOptions(refine=False), out_dir=root / "closed", report=False)
    return {"refined": root / "refined", "closed": root / "closed"}


# ------------------------------------------------------------------------------ a pose-only session's noise
def test_a_pose_only_report_states_the_tracker_s_noise_and_no_pixels(pose_only):
    """Its noise section showed 'Corner noise σ — px' and 'Reprojection RMS — → — px' rows, and its offsets spoke
    of the pixel noise the refinement weighs the views by: a pose-only session has no pixels."""
    tn = json.loads((pose_only / "result.json").read_text())["refinement"]["tracker_noise"]
    assert (tn["source"], tn["sigma_deg"], tn["sigma_mm"], tn["sigma_mm_along"]) == ("stated", 0.2, 0.5, 0.5)
    md, text = _reports(pose_only)
    for noise in (_noise_section(md), _noise_section(text)):
        assert "px" not in noise and "Corner noise" not in noise and "Reprojection" not in noise, noise
        assert "Tracker noise σ, rotation, per axis" in noise and "0.2000°" in noise, noise
        assert "Tracker noise σ, translation across the optical axis (x, y), per axis" in noise, noise
        assert "Tracker noise σ, translation along the optical axis (z)" in noise and "0.500 mm" in noise, noise
        assert "stated with the session" in noise and "(estimated)" not in noise, noise
        assert "not modelled: part of the tracker's" in noise, noise  # the robot's poses taken as reported
    assert "| Tracker noise σ, rotation, per axis | 0.2000° |" in md
    for page in (md, text):
        assert "pixel noise" not in page and "Tracker and robot noise" in page and "Camera and noise model" not in page


def test_an_image_report_keeps_its_pixel_rows(images):
    md, text = _reports(images["refined"])
    for noise in (_noise_section(md), _noise_section(text)):
        assert "Corner noise σ" in noise and "Reprojection RMS before → after" in noise and "Tracker" not in noise


def test_a_pose_only_report_speaks_of_a_tracked_target_and_lists_no_image_settings(pose_only, images):
    """Its header said 'board on the table', its provenance 'SHA-256 of images and pose files', its target transform
    'the calibration board', its methods 'board spread', and its Configuration listed reprojection_rms_px,
    image_coverage and min_corners: a pose-only session has a tracked target and no images."""
    md, text = _reports(pose_only)
    config = _between(md, "<summary>Configuration", "</details>")
    for page in (md, text):
        words = re.sub(r"\b[Tp]_\w+", "", page)  # frame names (T_base_board, p_board) are the contract's
        assert "board" not in words.lower(), re.findall(r".{60}board.{60}", words, flags=re.I)
        assert "Eye-in-hand (camera on the robot's flange, target on the table)" in page
        assert "Input hash (SHA-256 of the pose and session files)" in page and "images" not in words
        assert "target spread" in page and "pose of the tracked target in the base frame" in page
    assert "Target transform `T_base_board`" in md
    for setting in ("reprojection_rms_px", "image_coverage", "min_corners", "corner_outlier_sigmas", "intrinsics"):
        assert setting not in config, setting
    assert "k3" not in config and "predicted_error_mm: {warn_above: 2.0, fail_above: 5.0}" in config
    assert "max_outlier_rounds: 6" in config
    md, text = _reports(images["refined"])  # an image session keeps its words and settings
    config = _between(md, "<summary>Configuration", "</details>")
    for page in (md, text):
        assert "board on the table" in page and "SHA-256 of images and pose files" in page and "board spread" in page
    assert "Board transform `T_base_board` (pose of the calibration board" in md
    assert all(k in config for k in ("reprojection_rms_px", "image_coverage", "min_corners", "fix_k3"))


def test_the_noise_rows_of_an_estimated_tracker_say_which_sigma_the_views_could_not_resolve():
    from handeye.report.sections.models import _noise

    ref = {
        "sigma_px": float("nan"),
        "tracker_noise": {
            "sigma_deg": 0.1,
            "sigma_mm": 0.4,
            "sigma_mm_along": 2.0,
            "source": "estimated",
            "resolved": {"rot": True, "trans": True, "trans_along": False},
            "tail_dof": 4.0,
        },
    }
    n = _noise(ref, tracked=True)
    assert not n["pixels"] and n["estimated"] and n["tracker"]["source"] == "estimated from the views"
    assert [r["held"] for r in n["tracker"]["rows"]] == [False, False, True] and n["tracker"]["tail_dof"] == 4.0
    image = _noise({"sigma_px": 0.2, "tracker_noise": ref["tracker_noise"]})  # not tracked: the pixel rows
    assert image["pixels"] and image["tracker"] is None


def _far_closed_forms() -> tuple[list, dict]:
    """Three closed forms 9 σ from the result, their offsets small (rows and options of offset_explanation)."""
    rows = [
        {"name": m, "kind": "closed_form", "d_mm": d, "d_deg": g, "sigma": 9.0, "offset_mm": [d, 0.0, 0.0]}
        for m, d, g in (("tsai", 0.036, 0.0026), ("park", 0.071, 0.0030), ("li", 0.05, 0.0028))
    ]
    return rows, dict(
        limit_sigma=4.1, halves_m2=None, halves_m2_limit=16.8, robot_mm=None, robot_deg=None, robot_model=""
    )


def test_the_offsets_explanation_names_the_tracker_s_noise_for_a_pose_only_session():
    from handeye.report.uncertainty import offset_explanation

    rows, kw = _far_closed_forms()
    images, tracked = offset_explanation(rows, **kw), offset_explanation(rows, **kw, tracked=True)
    assert "ignore the pixel noise" in images[1] and "by its pixel noise" in images[2]
    assert not any("pixel" in t for t in tracked)
    assert "ignore the tracker's noise" in tracked[1] and "by the tracker's noise" in tracked[2]


def test_small_offsets_from_the_closed_forms_do_not_read_as_zero():
    """0.036-0.071 mm and 0.0026-0.0030 deg from the closed forms, at 9 σ, read '0.0-0.1 mm and 0.00-0.00°'."""
    from handeye.report.uncertainty import offset_explanation

    rows, kw = _far_closed_forms()
    text = offset_explanation(rows, **kw)
    assert "lies 0.036-0.071 mm and 0.0026-0.0030° (9.0-9.0 σ) from every closed form" in text[0]
    robot = offset_explanation(rows, **(kw | {"robot_mm": 0.001, "robot_deg": 0.000057, "robot_model": "iid"}))
    assert "(iid: 0.0010 mm / 0.000057° per view, estimated)" in robot[-1]


# ------------------------------------------------------------------------------ the offsets from the closed forms
def test_the_offsets_table_says_what_its_sigmas_measure_and_marks_only_a_half(images, tmp_path):
    """Every closed form past 4.1 σ was bold and 'a departure' while the diagnostics found nothing wrong: the
    sigmas are the result's own uncertainty, and a closed form past them is usually its own error."""
    from handeye.output import write_json

    res = json.loads((images["refined"] / "result.json").read_text())
    for e in res["closed_form"].values():
        e["diff_to_result_sigma"] = 9.0  # every closed form far, as on real data
    res["refinement"]["validation"]["halves"]["odd"]["diff_to_result_sigma"] = 8.0
    res["refinement"]["validation"]["halves"]["even"]["diff_to_result_sigma"] = 1.0
    folder = tmp_path / "r"
    folder.mkdir()
    write_json(folder / "result.json", res)
    (folder / "observations.json").write_bytes((images["refined"] / "observations.json").read_bytes())
    md, text = _reports(folder)
    for page in (md, text):
        assert "departure" not in page
        assert "σ, the result's own uncertainty (its verdict covariance" in page
        assert "for a closed form that is usually the closed form's own error (it ignores the noise)" in page
    table = _between(md, "| Against |", "\n\n")
    assert "**9.0**" not in table and table.count("| 9.0 |") == len(res["closed_form"])
    assert "**8.0**" in table and "**1.0**" not in table  # the half past the limit, alone
    assert "<strong>9.0</strong>" not in (folder / "report.html").read_text()


def test_a_closed_form_only_report_speaks_of_no_refined_result_and_no_ratio(images):
    md, text = _reports(images["closed"], plots=True)
    caption = _between(md, "*Uncertainty of the translation.*", "\n")
    assert "No covariance (closed form only)" in caption and "refined result" not in caption
    assert "Ratio held-out" not in md and "A ratio near 1" not in md and "A ratio near 1" not in text
    refined, _ = _reports(images["refined"])
    assert "Ratio held-out / predicted" in refined and "A ratio near 1 means" in refined


def test_report_command_line_is_the_run_s_as_typed_and_the_batch_s_inside_recorded_as(monkeypatch):
    """The report's "Report command line" row comes from the one place that records a run's command line: it
    names ``python -m handeye``, not ``__main__.py``, and in a batch's session process the batch's command."""
    from handeye.output import recorded_as
    from handeye.report.sections.provenance import _provenance

    def report_row(res):
        rows = {r["name"]: r["value"] for r in _provenance(res, {}, "configs/qa.yaml")["rows"]}
        return rows.get("Report command line")

    res = {"provenance": {"command_line": "handeye calibrate s1"}}
    monkeypatch.setattr("sys.argv", ["/venv/lib/python3.11/site-packages/handeye/__main__.py", "report", "out"])
    assert report_row(res) == "python -m handeye report out"
    with recorded_as(command_line="handeye batch /data --out /qa", paths={}):
        assert report_row(res) == "handeye batch /data --out /qa"
    assert report_row({"provenance": {"command_line": "python -m handeye report out"}}) is None  # the same: once


def test_the_run_time_row_names_the_stages_in_words():
    """The report's "Run time" row says "board poses", not result.json's key ``board_poses``."""
    from handeye.report.sections.provenance import _provenance

    res = {"provenance": {}, "seconds": {"detect": 0.21, "board_poses": 0.01, "total": 1.2}}
    rows = {r["name"]: r["value"] for r in _provenance(res, {}, "configs/qa.yaml")["rows"]}
    assert rows["Run time"] == "detect 0.21 s, board poses 0.01 s, total 1.20 s"


def test_the_advice_on_too_few_views_is_one_number_everywhere():
    """A 3-view report said "Collect 15-25 views" (the QA check, the advice) beside the finding's "capture 7 or more
    further views" toward its 10-20: every place gives the diagnostics' recommended count."""
    from handeye.diagnose.consistency import view_count_findings
    from handeye.diagnose.thresholds import thresholds
    from handeye.report.advice import ERROR_ADVICE
    from handeye.report.qa import _SPEC

    rec = f"{thresholds().views.recommended}-20"
    finding = view_count_findings(3)[0]
    assert finding.action.startswith(f"capture {thresholds().views.recommended - 3} or more further views")
    assert rec in finding.evidence and rec in ERROR_ADVICE["too_few_views"]
    assert rec in _SPEC["used_views"][4]({})
