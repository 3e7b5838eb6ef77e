"""The accuracy report: built from a result folder, opened in headless Chromium, Markdown rendered.

Smoke: a rendered synthetic session (one hidden view, one robot-pose outlier) calibrated with the
joint refinement gives report.html / report.md. Correctness: the page renders in a real browser with
no console errors and every image decoded; it is self-contained (no external URL, a copy elsewhere
still renders); the Markdown renders and links only existing files; the numbers agree with the
refinement. Failure: a session whose board is never found still gets a report that says why and what
to change. QA: site thresholds change the verdict; a bad QA file is a one-line error.
"""
from __future__ import annotations

import html as html_lib
import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest
import yaml

from handeye.pipeline import CalibrateOptions, run_calibration
from handeye.results import observations_dict, result_dict
from handeye.output import write_json
from handeye.session import load_session
from handeye.sim.synth import default_intrinsics, write_vendor_session

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (scripts/test.sh installs it)")
REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "ical-mako-charuco-eye-to-hand"


# ------------------------------------------------------------------------------ fixtures
def _calibrated(session_dir: Path, out: Path, *, refine: bool):
    run = run_calibration(load_session(session_dir), CalibrateOptions(refine=refine))
    res = result_dict(run)
    write_json(out / "observations.json", observations_dict(run))
    write_json(out / "result.json", res)
    return run, res


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """A refined eye-in-hand session with view 4 hidden and view 7 given a wrong robot pose."""
    root = tmp_path_factory.mktemp("report_synth")
    session = write_vendor_session(root / "session", mode="eye_in_hand", n_views=10, seed=5, hidden_views=("4",),
                                   outlier_views=("7",), image_noise=1.0, intrinsics=default_intrinsics(640, 480),
                                   supersample=3)
    out = root / "result"
    run, res = _calibrated(session, out, refine=True)
    assert res["status"] == "ok", res["failure_reason"]
    # what the diagnostics helper adds; the report must show it whatever else is there
    res["diagnostics"] = {
        "findings": [
            {"code": "robot_pose_disagrees", "severity": "warn", "title": "Robot pose disagrees with the camera",
             "evidence": "view 7: 17.6 mm / 7.8 deg", "action": "retake view 7 with the robot at rest",
             "view_ids": ["7"]},
            {"code": "overexposed", "severity": "info", "title": "White squares clipped in 1 view(s)",
             "evidence": "view 2: 12% of the board saturated", "action": "shorten the exposure", "view_ids": ["2"]},
        ],
        "cross_validation": {"summary": "the spread between folds matches the predicted uncertainty",
                             "verdict": "consistent", "scheme": "leave-one-out", "n_folds": 9,
                             "jackknife_sigma_rot_deg": [0.01, 0.02, 0.01], "jackknife_sigma_trans_mm": [0.05, 0.06, 0.04],
                             "predicted_sigma_rot_deg": [0.01, 0.02, 0.01], "predicted_sigma_trans_mm": [0.05, 0.05, 0.04],
                             "ratio_rot": 1.0, "ratio_trans": 1.1,
                             "per_view": [{"view": "1", "held_out_rms_px": 0.3, "x_shift_mm": 0.02}]},
    }
    write_json(out / "result.json", res)
    from handeye.report import write_reports

    paths = write_reports(run, res, out, strict=True)
    return {"run": run, "res": res, "out": out, "paths": paths, "session": session}


@pytest.fixture(scope="module")
def failed(tmp_path_factory, synthetic):
    """The same images with a board description that does not match: the target is never found."""
    root = tmp_path_factory.mktemp("report_failed")
    session = root / "session"
    shutil.copytree(synthetic["session"], session)
    cfg = yaml.safe_load((session / "config.yaml").read_text())
    cfg["checkerboard_args"]["XX"] += 2
    (session / "config.yaml").write_text(yaml.safe_dump(cfg))
    out = root / "result"
    run, res = _calibrated(session, out, refine=False)
    assert res["status"] == "failed"
    from handeye.report import write_reports

    return {"res": res, "out": out, "paths": write_reports(run, res, out, strict=True)}


# ------------------------------------------------------------------------------ browser helpers
CHECK_SCRIPT = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0); })
                .map(function (i) { return i.alt; });
  document.body.setAttribute('data-check', JSON.stringify({n: imgs.length, bad: bad,
      height: document.documentElement.scrollHeight}));
});
</script>
</body>"""


def _chromium(args: list, tmp: Path) -> subprocess.CompletedProcess:
    profile = tmp / "chromium-profile"
    profile.mkdir(exist_ok=True)
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--disable-dev-shm-usage", f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=180)


def _console_errors(stderr: str) -> list:
    bad = []
    for line in stderr.splitlines():
        if "CONSOLE" in line or "Uncaught" in line or "net::ERR_" in line or "Failed to load resource" in line:
            bad.append(line)
    return bad


def _browser_check(report: Path, tmp: Path) -> dict:
    """Open a copy of the report (elsewhere, so relative links would break) with an image check appended."""
    copy = tmp / "elsewhere" / "copy.html"
    copy.parent.mkdir(parents=True, exist_ok=True)
    text = report.read_text(encoding="utf-8")
    assert text.count("</body>") == 1
    copy.write_text(text.replace("</body>", CHECK_SCRIPT), encoding="utf-8")
    p = _chromium(["--virtual-time-budget=15000", "--dump-dom", copy.as_uri()], tmp)
    assert p.returncode == 0, p.stderr[-2000:]
    m = re.search(r'data-check="([^"]*)"', p.stdout)
    assert m, "the page did not finish loading: " + p.stdout[-500:]
    check = json.loads(html_lib.unescape(m.group(1)))
    check["console_errors"] = _console_errors(p.stderr)
    return check


def _screenshot(report: Path, tmp: Path, name: str) -> Path:
    shot = tmp / name
    p = _chromium([f"--screenshot={shot}", "--window-size=1280,4000", "--hide-scrollbars", report.as_uri()], tmp)
    assert p.returncode == 0, p.stderr[-2000:]
    assert not _console_errors(p.stderr), _console_errors(p.stderr)
    return shot


class _Links(HTMLParser):
    def __init__(self):
        super().__init__()
        self.urls, self.tags = [], []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        for k, v in attrs:
            if k in ("src", "href", "srcset", "poster", "data") and v is not None:
                self.urls.append((tag, k, v))


def _assert_self_contained(html: str):
    p = _Links()
    p.feed(html)
    assert "script" not in p.tags and "link" not in p.tags and "iframe" not in p.tags
    for tag, k, v in p.urls:
        assert v.startswith("data:image/png;base64,") or v.startswith("#"), (tag, k, v[:80])
    assert not re.search(r"url\(\s*['\"]?(?!data:)", html), "CSS must not load anything"
    assert "@import" not in html and "http://" not in html and "https://" not in html


def _pngs_decode(html: str) -> int:
    import base64

    import cv2

    n = 0
    for b64 in re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', html):
        img = cv2.imdecode(np.frombuffer(base64.b64decode(b64), np.uint8), cv2.IMREAD_UNCHANGED)
        assert img is not None and img.shape[0] > 10 and img.shape[1] > 10
        n += 1
    return n


def _markdown_ok(md_path: Path) -> str:
    markdown = pytest.importorskip("markdown", reason="pip install markdown (in handeye[test])")
    text = md_path.read_text(encoding="utf-8")
    links = re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", text)
    for rel in links:
        assert not re.match(r"^[a-z]+://", rel) and (md_path.parent / rel).is_file(), rel
    html = markdown.markdown(text, extensions=["tables", "fenced_code"])
    assert html.count("<img") == len(links)
    assert "<table>" in html
    assert "| ---" not in html and "|---|" not in html, "a table did not render"
    return html


# ------------------------------------------------------------------------------ tests
def test_reports_are_written_beside_the_result(synthetic):
    out = synthetic["out"]
    assert [p.name for p in synthetic["paths"]] == ["report.html", "report.md"]
    html = (out / "report.html").read_text(encoding="utf-8")
    _assert_self_contained(html)
    n_img = _pngs_decode(html)
    assert n_img >= 6 + 10  # plots + a thumbnail per view (the hidden view's image is shown too)
    for key in ("residuals", "per_view", "coverage", "poses", "rotations", "uncertainty"):
        assert f'id="fig-{key}"' in html, key


@needs_chromium
def test_html_renders_in_chromium_without_errors_or_broken_images(synthetic, tmp_path):
    report = synthetic["out"] / "report.html"
    check = _browser_check(report, tmp_path)
    assert check["n"] >= 16 and check["bad"] == [], check
    assert check["console_errors"] == [], check["console_errors"]
    assert check["height"] > 3000  # the whole report, not an error page
    shot = _screenshot(report, tmp_path, "report.png")
    import cv2

    img = cv2.imread(str(shot))
    assert img is not None and img.shape[1] == 1280
    assert float(img.std()) > 20  # not a blank page
    print(f"screenshot: {shot}")


def test_markdown_renders_with_every_image_beside_it(synthetic):
    md = synthetic["out"] / "report.md"
    html = _markdown_ok(md)
    files = sorted(p.name for p in (synthetic["out"] / "report_files").glob("*.png"))
    assert "residuals.png" in files and "view_4.png" in files
    assert "Verdict" in html and "T_end_cam" in html


def test_report_content_verdict_result_views_and_provenance(synthetic):
    text = (synthetic["out"] / "report.md").read_text(encoding="utf-8")
    res = synthetic["res"]
    ref = res["refinement"]
    # verdict first
    first = text.index("## Verdict")
    assert first < text.index("## Result") < text.index("## Views") < text.index("## Provenance")
    # the result in every form, frames named, with bounds and the predicted error of the refinement
    for s in ("T_end_cam", "p_end = T_end_cam · p_cam", "quaternion w, x, y, z", "x, y, z, w",
              "R = Rz·Ry·Rx", "95 % interval", res["hand_eye"]["vendor_pose_line"]):
        assert s in text, s
    assert f"{ref['predicted_error_mm']:.2f} mm" in text
    # every closed-form method and the refined result
    for m in res["closed_form"]:
        assert f"| {m}" in text or f"| **{m}" in text, m
    assert "joint refinement (result)" in text
    # per view: the hidden view is dropped with its reason, the outlier is flagged with its reason
    row4 = next(line for line in text.splitlines() if line.startswith("| **4** |"))
    assert "dropped" in row4 and "not found" in row4
    row7 = next(line for line in text.splitlines() if line.startswith("| **7** |"))
    assert "flagged" in row7 and "robot pose" in row7
    # diagnostics: findings and cross-validation are shown
    assert "Robot pose disagrees with the camera" in text and "Validation on held-out views" in text
    # provenance
    for s in ("Command line", res["provenance"]["inputs_sha256"], "handeye version", "QA thresholds"):
        assert s in text, s


def test_report_numbers_agree_with_the_refinement(synthetic, tmp_path):
    """The report's own uncertainty propagation reproduces the refinement's sigmas and predicted error."""
    from handeye.report.analysis import form_sigmas, predicted_point_error, radius95_mm

    res = synthetic["res"]
    ref = res["refinement"]
    T = np.asarray(res["T_end_cam"])
    cov = np.asarray(ref["cov_x_6x6"])
    s = form_sigmas(T, cov)
    np.testing.assert_allclose(s["translation_mm"], ref["sigma_trans_mm"], rtol=1e-4)
    np.testing.assert_allclose(s["rot_cam_deg"], ref["sigma_rot_deg"], rtol=1e-6)
    p = predicted_point_error(T, cov, working_distance_m=ref["working_distance_m"])
    assert p["rms_mm"] == pytest.approx(ref["predicted_error_mm"], rel=1e-6)
    from scipy.stats import chi2

    assert radius95_mm(np.eye(3) * 4.0) == pytest.approx(2.0 * np.sqrt(chi2.ppf(0.95, 3)), rel=0.01)


def test_euler_sigma_propagation_matches_sampling():
    """Delta-method Euler sigmas against sampled perturbations T · Exp(xi)."""
    from scipy.spatial.transform import Rotation

    from handeye.conventions import vendor_euler_from_R
    from handeye.frames import make_T
    from handeye.report.analysis import form_sigmas

    rng = np.random.default_rng(3)
    T = make_T(Rotation.from_euler("xyz", [0.3, -0.4, 1.2]).as_matrix(), [0.05, -0.02, 0.1])
    L = rng.normal(size=(6, 6)) * np.r_[[1e-3] * 3, [2e-4] * 3][:, None]
    cov = L @ L.T
    s = form_sigmas(T, cov)
    xi = rng.multivariate_normal(np.zeros(6), cov, size=20000)
    eul = np.array([vendor_euler_from_R(T[:3, :3] @ Rotation.from_rotvec(x[:3]).as_matrix()) for x in xi])
    np.testing.assert_allclose(np.degrees(eul.std(axis=0)), s["euler_vendor_deg"], rtol=0.05)


def test_failed_session_report_says_why_and_what_to_change(failed, tmp_path):
    out = failed["out"]
    html = (out / "report.html").read_text(encoding="utf-8")
    md = (out / "report.md").read_text(encoding="utf-8")
    _assert_self_contained(html)
    assert "FAIL" in md.split("## Verdict", 1)[1][:40]
    assert "could not be calibrated" in md and "Why the calibration failed" in md and "What to change" in md
    assert "found in only 0 of 10 images" in md
    assert "inner corners" in md  # the action names what to check
    _markdown_ok(out / "report.md")
    # the views that failed are listed with their reason and an image, so the cause can be seen
    assert md.count("not found") >= 10
    assert _pngs_decode(html) == 10


@needs_chromium
def test_failed_session_report_renders_in_chromium(failed, tmp_path):
    check = _browser_check(failed["out"] / "report.html", tmp_path)
    assert check["bad"] == [] and check["console_errors"] == [], check


def test_report_without_views_or_observations_still_builds(tmp_path):
    """A session that does not even load: no views, no observations, unknown mode."""
    from handeye.report import write_reports

    res = {"handeye_result": 1, "status": "failed", "mode": "unknown", "views": [], "n_views": {"total": 0, "used": 0},
           "failure_reason": "/x/session.yaml: unknown target type; expected chessboard | charuco; got 'circles'",
           "session": {"path": "/x", "format": "unreadable"}, "provenance": {"handeye_version": "0"}}
    paths = write_reports(None, res, tmp_path, strict=True)
    md = paths[1].read_text(encoding="utf-8")
    assert "unknown target type" in md.lower() and "No views were read" in md and "Mounting mode unknown" in md
    _assert_self_contained(paths[0].read_text(encoding="utf-8"))


def test_missing_images_and_stale_observations_do_not_break_the_report(synthetic, tmp_path):
    """The report rebuilt where the images are gone: placeholders, no broken <img>."""
    from handeye.report import write_reports

    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    for v in obs["views"].values():
        v["image"] = str(tmp_path / "gone" / Path(v["image"]).name)
    obs["views"]["999"] = obs["views"]["1"]  # a view that is not in this result (stale file)
    res["session"]["path"] = str(tmp_path / "gone")
    write_json(tmp_path / "observations.json", obs)
    paths = write_reports(None, res, tmp_path, formats=("md",), strict=True, plots=False)
    md = paths[0].read_text(encoding="utf-8")
    assert "image not available" in md and "| **999** |" not in md
    _markdown_ok(paths[0])


def test_site_thresholds_change_the_verdict(synthetic, tmp_path):
    from handeye.report import build_report_context

    out, res = synthetic["out"], synthetic["res"]
    base = build_report_context(None, res, out, make_plots=False)["verdict"]
    assert base.status in ("pass", "warn")
    strict = tmp_path / "strict.yaml"
    strict.write_text("checks:\n  predicted_error_mm: {warn_above: 0.001, fail_above: 0.002}\n")
    v = build_report_context(None, res, out, qa=strict, make_plots=False)["verdict"]
    assert v.status == "fail"
    c = next(c for c in v.checks if c.key == "predicted_error_mm")
    assert c.status == "fail" and "0.002" in c.why and c.action
    assert "predicted position error" in v.headline and str(strict) in v.thresholds_source
    # the working distance of the site moves the predicted error (error grows with distance)
    far = tmp_path / "far.yaml"
    far.write_text("working_distance_m: 3.0\n")
    pred_near = build_report_context(None, res, out, make_plots=False)["result"]["pred"]["rms_mm"]
    ctx_far = build_report_context(None, res, out, qa=far, make_plots=False)
    assert ctx_far["result"]["working_distance_m"] == 3.0 and ctx_far["result"]["pred"]["rms_mm"] > pred_near
    lenient = tmp_path / "lenient.yaml"
    from handeye.report import load_qa

    shipped = load_qa()["checks"]
    lenient.write_text(yaml.safe_dump({"include_diagnostics": False, "checks": {  # switch off the view-count checks
        k: {lim: None for lim in shipped[k]} for k in ("dropped_share", "used_views", "image_coverage")}}))
    v = build_report_context(None, res, out, qa=lenient, make_plots=False)["verdict"]
    assert v.status == "pass", [(c.key, c.status) for c in v.checks]


def test_diagnostic_findings_count_towards_the_verdict(synthetic, tmp_path):
    from handeye.report import build_report_context

    res = json.loads(json.dumps(synthetic["res"]))
    res["diagnostics"]["findings"].append({"code": "translation_units", "severity": "fail",
                                           "title": "Robot translations are in millimetres, read as metres",
                                           "evidence": "...", "action": "set translation_unit: mm", "view_ids": []})
    v = build_report_context(None, res, synthetic["out"], make_plots=False)["verdict"]
    assert v.status == "fail" and "millimetres" in v.headline


def test_bad_site_qa_file_is_a_one_line_error(synthetic, tmp_path):
    from handeye.cli import main
    from handeye.errors import ConfigError
    from handeye.report import load_qa

    bad = tmp_path / "bad.yaml"
    bad.write_text("checks:\n  reprojection_rms_px: {warn_over: 1}\n")
    with pytest.raises(ConfigError, match="warn_over"):
        load_qa(bad)
    bad.write_text("no_such_setting: 1\n")
    with pytest.raises(ConfigError, match="no_such_setting"):
        load_qa(bad)
    assert main(["-q", "report", str(synthetic["out"]), "--qa", str(bad)]) != 0


def test_report_command_rebuilds_from_the_folder(synthetic, tmp_path, capsys):
    from handeye.cli import main

    qa = tmp_path / "qa.yaml"
    qa.write_text("checks:\n  reprojection_rms_px: {warn_above: 0.0001, fail_above: 0.0002}\n")
    dest = tmp_path / "rebuilt"
    assert main(["-q", "report", str(synthetic["out"]), "--qa", str(qa), "--out", str(dest), "--format", "md"]) == 0
    md = (dest / "report.md").read_text(encoding="utf-8")
    assert "## Verdict: **FAIL**" in md and "Reprojection RMS" in md
    assert "report.md" in capsys.readouterr().out


@pytest.mark.realdata
@pytest.mark.skipif(not REAL.exists(), reason="needs ../shared/data/ical-mako-charuco-eye-to-hand")
def test_clean_real_dataset_is_not_reported_as_failed(tmp_path):
    from handeye.session.importers import import_ical
    from handeye.report import write_reports

    session = import_ical(REAL, tmp_path / "session")
    run, res = _calibrated(Path(session).parent, tmp_path / "out", refine=False)
    paths = write_reports(run, res, tmp_path / "out", formats=("md",), strict=True, plots=False)
    md = paths[0].read_text(encoding="utf-8")
    assert "## Verdict: **FAIL**" not in md
    assert "| **2** |" in md and "dropped" in md  # the one view with too few corners
    _markdown_ok(paths[0])
