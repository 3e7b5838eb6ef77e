"""The accuracy report, built from a result folder alone.

Smoke: a rendered synthetic session (one hidden view, one robot-pose outlier) calibrated by the
product workflow gives report.html / report.md. Correctness: the page renders in a real browser with
no console errors and every image decoded; it is self-contained (no external URL, a copy elsewhere
still renders); the Markdown renders and links only existing files; the numbers agree with the
refinement; the verdict moves to known values with site thresholds; names are escaped. Failure: a
session whose board is never found still gets a report that says why (keyed on the error's code) and
what to change; numbers a finding distrusts are not shown green.
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

from handeye.pipeline import CalibrateOptions
from handeye.sim.scenarios import default_intrinsics
from handeye.sim.vendor import write_vendor_session
from handeye.workflow import calibrate_session

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (scripts/test.sh installs it)")


# ------------------------------------------------------------------------------ fixtures
@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    """A refined eye-in-hand session with view 4 hidden and view 7 given a wrong robot pose, written by
    the workflow (result.json with diagnostics, observations.json, thumbnails/, both reports)."""
    root = tmp_path_factory.mktemp("report_synth")
    session = write_vendor_session(
        root / "session",
        mode="eye_in_hand",
        n_views=10,
        seed=5,
        hidden_views=("4",),
        outlier_views=("7",),
        image_noise=1.0,
        intrinsics=default_intrinsics(640, 480),
        supersample=3,
    )
    out = root / "result"
    wf = calibrate_session(session, options=CalibrateOptions(refine=True), out_dir=out)
    assert wf.status == "ok", wf.result.get("failure_reason")
    res = json.loads((out / "result.json").read_text(encoding="utf-8"))
    return {"res": res, "out": out, "paths": list(wf.report_paths), "session": session}


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
    wf = calibrate_session(session, options=CalibrateOptions(refine=False), out_dir=out)
    assert wf.status == "failed"
    res = json.loads((out / "result.json").read_text(encoding="utf-8"))
    return {"res": res, "out": out, "paths": list(wf.report_paths)}


def _folder(tmp: Path, res: dict, obs: dict | None = None) -> Path:
    """A result folder holding only the given result.json (and observations.json)."""
    from handeye.output import write_json

    tmp.mkdir(parents=True, exist_ok=True)
    write_json(tmp / "result.json", res)
    if obs is not None:
        write_json(tmp / "observations.json", obs)
    return tmp


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
    cmd = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-dev-shm-usage",
        f"--user-data-dir={profile}",
        "--enable-logging=stderr",
        "--v=0",
        *args,
    ]
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
        assert re.match(r"^data:image/(png|jpeg);base64,", v) or v.startswith("#"), (tag, k, v[:80])
    assert not re.search(r"url\(\s*['\"]?(?!data:)", html), "CSS must not load anything"
    assert "@import" not in html and "http://" not in html and "https://" not in html


def _images_decode(html: str) -> dict:
    """Decode every inlined image; returns {"png": n, "jpeg": n}."""
    import base64

    import cv2

    n = {"png": 0, "jpeg": 0}
    for kind, b64 in re.findall(r'src="data:image/(png|jpeg);base64,([A-Za-z0-9+/=]+)"', html):
        img = cv2.imdecode(np.frombuffer(base64.b64decode(b64), np.uint8), cv2.IMREAD_UNCHANGED)
        assert img is not None and img.shape[0] > 10 and img.shape[1] > 10
        n[kind] += 1
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
    n = _images_decode(html)
    assert n["png"] == 6, n  # every figure below
    assert n["jpeg"] == len(list((out / "thumbnails").glob("*.jpg"))), n  # every thumbnail the folder holds
    for key in ("residuals", "per_view", "coverage", "poses", "rotations", "uncertainty"):
        assert f'id="fig-{key}"' in html, key
    ids = re.findall(r'\sid="([^"]+)"', html)
    assert len(ids) == len(set(ids)), sorted(i for i in ids if ids.count(i) > 1)  # each anchor once
    for target in re.findall(r'href="#([^"]+)"', html):
        assert target in ids, target  # no link to a section the report does not have


@needs_chromium
def test_html_renders_in_chromium_without_errors_or_broken_images(synthetic, tmp_path):
    report = synthetic["out"] / "report.html"
    check = _browser_check(report, tmp_path)
    n_thumbs = len(list((synthetic["out"] / "thumbnails").glob("*.jpg")))
    assert check["n"] == 6 + n_thumbs and check["bad"] == [], check
    assert check["console_errors"] == [], check["console_errors"]
    assert check["height"] > 3000  # the whole report, not an error page
    shot = _screenshot(report, tmp_path, "report.png")
    import cv2

    img = cv2.imread(str(shot))
    assert img is not None and img.shape[1] == 1280
    assert float(img.std()) > 20  # not a blank page


def test_markdown_renders_with_every_image_beside_it(synthetic):
    out = synthetic["out"]
    html = _markdown_ok(out / "report.md")
    files = sorted(p.name for p in (out / "report_files").iterdir())
    assert files == sorted(
        f"{k}.png" for k in ("residuals", "per_view", "coverage", "poses", "rotations", "uncertainty")
    )
    # in the result folder the thumbnails are linked where they are, not copied
    links = re.findall(r"!\[view [^\]]*\]\(([^)]+)\)", (out / "report.md").read_text(encoding="utf-8"))
    assert sorted(links) == sorted(f"thumbnails/{p.name}" for p in (out / "thumbnails").glob("*.jpg"))
    assert "T_end_cam" in html
    for name in files:  # every figure is an image of the rendered Markdown, not the text of a broken link
        assert re.search(rf'<img alt="[^"]+" src="report_files/{name}"', html), name
    assert "](report_files" not in re.sub(r"!\[[^\]]*\]\(report_files/[a-z_]+\.png\)", "", html)


def test_report_content_verdict_result_views_and_provenance(synthetic):
    text = (synthetic["out"] / "report.md").read_text(encoding="utf-8")
    res = synthetic["res"]
    ref = res["refinement"]
    assert text.index("## Verdict") < text.index("## Result") < text.index("## Views") < text.index("## Provenance")
    # the result in every form, frames named, with bounds and the predicted error of the refinement
    for s in ("p_end = T_end_cam · p_cam", "95 % interval", res["hand_eye"]["vendor_pose_line"]):
        assert s in text, s
    assert f"{ref['predicted_error_mm']:.2f} mm" in text
    T = np.asarray(res["T_end_cam"])
    assert f"{T[0, 3] * 1e3:+.2f}" in text  # the translation as the table prints it
    for m, e in res["closed_form"].items():  # every closed-form method with its translation
        row = next(line for line in text.splitlines() if re.match(rf"^\| (\*\*)?{m}(\*\*)?( \(seed\))? \|", line))
        if e["status"] == "ok":
            assert f"{e['translation_mm'][0]:+.2f}" in row, row
    assert "joint refinement (result)" in text
    # per view: each view's status as result.json has it; the hidden view dropped with its reason,
    # the outlier dropped with the refinement's reason
    section = text.split("## Views", 1)[1].split("\n## ", 1)[0]
    rows = {
        line.split("|")[1].strip(" *"): line for line in section.splitlines() if re.match(r"^\| \*\*\S+\*\* \|", line)
    }
    assert sorted(rows) == sorted(v["id"] for v in res["views"])
    for v in res["views"]:
        status = rows[v["id"]].split("|")[3].strip()
        assert (status == "used") == v["used"], (v["id"], status)
    assert "dropped" in rows["4"]
    view4 = next(v for v in res["views"] if v["id"] == "4")
    assert view4["reason"].split(": ", 1)[-1][:30] in rows["4"]
    outl7 = [o for o in ref["outliers"] if str(o["view_id"]) == "7"]
    assert outl7 and "| dropped |" in rows["7"] and outl7[0]["reason"].split(": ", 1)[-1][:30] in rows["7"]
    # every diagnostic finding of the run is shown with its code
    for f in res["diagnostics"]["findings"]:
        assert f"`{f['code']}`" in text, f["code"]
    if res["diagnostics"].get("cross_validation"):
        assert "Validation on held-out views" in text
    # provenance
    for s in (res["provenance"]["inputs_sha256"], res["provenance"]["command_line"][:20]):
        assert s in text, s


def test_report_numbers_agree_with_the_refinement(synthetic):
    """The report's own uncertainty propagation reproduces the refinement's sigmas and predicted error: those
    of the covariance the verdict uses (``cov_x_6x6_verdict``, the model's or the validated one)."""
    from handeye.report.uncertainty import form_sigmas, predicted_point_error, radius95_mm

    res = synthetic["res"]
    ref = res["refinement"]
    T = np.asarray(res["T_end_cam"])
    cov = np.asarray(ref["cov_x_6x6_verdict"])
    s = form_sigmas(T, cov)
    np.testing.assert_allclose(s["translation_mm"], ref["sigma_trans_mm"], rtol=1e-4)
    np.testing.assert_allclose(s["rot_cam_deg"], ref["sigma_rot_deg"], rtol=1e-6)
    p = predicted_point_error(T, cov, working_distance_m=ref["working_distance_m"])
    assert p["rms_mm"] == pytest.approx(ref["predicted_error_mm"], rel=1e-6)
    from scipy.stats import chi2

    # isotropic 2 mm per axis: r95 = 2 * sqrt(chi2_3(0.95)); 60k samples estimate it to ~0.4 % (1 sigma)
    assert radius95_mm(np.eye(3) * 4.0) == pytest.approx(2.0 * np.sqrt(chi2.ppf(0.95, 3)), rel=0.012)


def test_offsets_and_methods_show_the_differences_result_json_stores(synthetic, tmp_path):
    """The closed forms' and the halves' differences to the result are result.json's (diff_to_result_deg, _mm,
    _sigma), not recomputed: a stored value changed in the file is the value shown; one not stored is NaN."""
    import copy

    from handeye.report import build_report_context

    res = copy.deepcopy(synthetic["res"])
    cf = {m: e for m, e in res["closed_form"].items() if e["status"] == "ok"}
    halves = res["refinement"]["validation"]["halves"]
    first = next(iter(cf))
    for k, e in enumerate([*cf.values(), halves["odd"], halves["even"]]):
        e.update(diff_to_result_deg=10.0 + k, diff_to_result_mm=20.0 + k, diff_to_result_sigma=30.0 + k)
    del cf[first]["diff_to_result_sigma"]
    ctx = build_report_context(_folder(tmp_path / "r", res, None), make_plots=False)
    rows = {r["name"]: r for r in ctx["offsets"]["rows"]}
    for k, m in enumerate(cf):
        assert (rows[m]["d_deg"], rows[m]["d_mm"]) == (10.0 + k, 20.0 + k), m
        assert rows[m]["sigma"] == 30.0 + k or (m == first and np.isnan(rows[m]["sigma"]) and not rows[m]["far"])
    n = len(cf)
    assert [(r["d_deg"], r["d_mm"], r["sigma"]) for r in ctx["offsets"]["rows"] if r["kind"] == "half"] == [
        (10.0 + n, 20.0 + n, 30.0 + n),
        (11.0 + n, 21.0 + n, 31.0 + n),
    ]
    methods = {m["name"]: m for m in ctx["methods"]}
    assert all((methods[m]["d_deg"], methods[m]["d_mm"]) == (10.0 + k, 20.0 + k) for k, m in enumerate(cf))


def test_euler_sigma_propagation_matches_sampling():
    """Delta-method Euler sigmas against sampled perturbations T · Exp(xi) (right tangent, as the covariance)."""
    from handeye.conventions import vendor_euler_from_R
    from handeye.frames import T_from_rotvec, se3_exp
    from handeye.report.uncertainty import form_sigmas

    rng = np.random.default_rng(3)
    T = T_from_rotvec([0.3, -0.4, 1.2], [0.05, -0.02, 0.1])
    L = rng.normal(size=(6, 6)) * np.r_[[1e-3] * 3, [2e-4] * 3][:, None]
    cov = L @ L.T
    s = form_sigmas(T, cov)
    xi = rng.multivariate_normal(np.zeros(6), cov, size=20000)
    Ts = T @ se3_exp(xi)
    eul = np.array([vendor_euler_from_R(Ti[:3, :3]) for Ti in Ts])
    tr = Ts[:, :3, 3] * 1e3
    # 20000 samples: a sampled sigma is within ~0.5 % (1 sigma) of the true one; allow 4 sigma
    np.testing.assert_allclose(np.degrees(eul.std(axis=0)), s["euler_vendor_deg"], rtol=0.02)
    np.testing.assert_allclose(tr.std(axis=0), s["translation_mm"], rtol=0.02)


def test_a_view_the_refinement_left_out_is_dropped_as_the_command_says_and_named_once(synthetic):
    """The command printed "view 7 (7.jpg) dropped: outlier: view 7: reported robot pose disagrees ..." and the
    report's views table called the same view "flagged": one word for one state, and the id said once."""
    from handeye.results import own_view_reason

    res = synthetic["res"]
    view7 = next(v for v in res["views"] if v["id"] == "7")
    assert not view7["used"] and view7["reason"].startswith("outlier: reported robot pose disagrees with the camera")
    assert "view 7" not in view7["reason"]
    assert "view 7: reported" in next(o["reason"] for o in res["refinement"]["outliers"] if str(o["view_id"]) == "7")
    md = (synthetic["out"] / "report.md").read_text(encoding="utf-8")
    row = next(line for line in md.splitlines() if line.startswith("| **7** |"))
    assert row.split("|")[3].strip() == "dropped" and "FAIL: outlier: reported robot pose disagrees" in row
    assert "flagged" not in md.split("## Views", 1)[1].split("\n## ", 1)[0]
    assert own_view_reason("outlier: view 12: corners", "12") == "outlier: corners"
    assert own_view_reason("view 3: 4 corners, need 8", "3") == "4 corners, need 8"
    assert own_view_reason("outlier: view 12: corners", "1") == "outlier: view 12: corners"  # another view's: kept


def test_no_two_lines_of_the_markdown_reports_run_together(synthetic, failed, joined_lines):
    """A failed run's "**Why the calibration failed:**" ran into "**What to change:**", a normal one's "Ratio
    held-out / predicted ..." into "Axes: ...", "**`T_end_cam`** — ..." into "4×4 homogeneous transform ..."."""
    for out in (synthetic["out"], failed["out"]):
        md = (out / "report.md").read_text(encoding="utf-8")
        assert joined_lines(md) == []
    md = (synthetic["out"] / "report.md").read_text(encoding="utf-8")
    assert re.search(r"^Ratio held-out / predicted .*\n\nAxes: ", md, flags=re.M)
    md = (failed["out"] / "report.md").read_text(encoding="utf-8")
    assert re.search(r"^\*\*Why the calibration failed:\*\* .*\n\n\*\*What to change:\*\*$", md, flags=re.M)


def test_failed_session_report_says_why_and_what_to_change(failed):
    from handeye.report.advice import ERROR_ADVICE

    out, res = failed["out"], failed["res"]
    html = (out / "report.html").read_text(encoding="utf-8")
    md = (out / "report.md").read_text(encoding="utf-8")
    _assert_self_contained(html)
    assert md.split("## Verdict", 1)[1].lstrip(": ").startswith("**FAIL**")
    assert "could not be calibrated" in md and "Why the calibration failed" in md and "What to change" in md
    err = res["error"]
    assert err["code"] == "target_not_found"
    assert err["what"][1:40] in md and f"`{err['code']}`" in md  # (first letter capitalised)
    assert ERROR_ADVICE["target_not_found"] in md  # the advice for this code
    _markdown_ok(out / "report.md")
    # every view is listed as dropped, with an image where the folder has one
    section = md.split("## Views", 1)[1].split("\n## ", 1)[0]
    rows = [line for line in section.splitlines() if re.match(r"^\| \*\*\S+\*\* \|", line)]
    assert len(rows) == 10 and all("| dropped |" in r for r in rows)
    assert _images_decode(html)["jpeg"] == len(list((out / "thumbnails").glob("*.jpg")))
    assert "no hand-eye transform was computed" in section and "constrain the hand-eye" not in section
    assert 'class="kpi pass"' not in html  # no green card without a result


@needs_chromium
def test_failed_session_report_renders_in_chromium(failed, tmp_path):
    check = _browser_check(failed["out"] / "report.html", tmp_path)
    assert check["bad"] == [] and check["console_errors"] == [], check


def test_advice_is_keyed_on_the_error_code_not_its_text(tmp_path):
    """A message that reads like one failure but carries another code gets the advice of its code."""
    from handeye.report import build_report_context
    from handeye.report.advice import ERROR_ADVICE

    res = {
        "status": "failed",
        "mode": "eye_in_hand",
        "views": [],
        "failure_reason": "x",
        "error": {
            "code": "motion_one_axis",
            "what": "the target was found in only 2 of 9 images",
            "file": "/s/session.yaml",
            "line": 3,
            "expected": None,
            "got": None,
            "fix": "rotate about another axis",
        },
    }
    f = build_report_context(_folder(tmp_path / "a", res), make_plots=False)["failure"]
    assert f["code"] == "motion_one_axis" and f["where"] == "/s/session.yaml:3"
    assert f["actions"] == ["Rotate about another axis.", ERROR_ADVICE["motion_one_axis"]]
    # a result without a structured error (written before errors had codes): its text, generic advice
    old = {
        "status": "failed",
        "mode": "eye_in_hand",
        "views": [],
        "failure_reason": "the target was found in only 0 of 10 images",
    }
    f = build_report_context(_folder(tmp_path / "b", old), make_plots=False)["failure"]
    assert f["code"] == "" and f["problem"] == "The target was found in only 0 of 10 images."
    assert ERROR_ADVICE["target_not_found"] not in f["actions"] and len(f["actions"]) == 1


def test_report_without_views_or_observations_still_builds(tmp_path):
    """A session that does not even load: no views, no observations, unknown mode."""
    from handeye.report import write_reports

    res = {
        "handeye_result": 1,
        "status": "failed",
        "mode": "unknown",
        "views": [],
        "n_views": {"total": 0, "used": 0},
        "failure_reason": "/x/session.yaml: unknown target type; expected chessboard | charuco; got 'circles'",
        "error": {
            "code": "config_error",
            "what": "unknown target type",
            "file": "/x/session.yaml",
            "expected": "chessboard | charuco",
            "got": "'circles'",
            "fix": None,
        },
        "session": {"path": "/x", "format": "unreadable"},
        "provenance": {"handeye_version": "0"},
    }
    paths = write_reports(_folder(tmp_path, res), strict=True)
    md = paths[1].read_text(encoding="utf-8")
    assert "Unknown target type; expected chessboard \\| charuco; got 'circles'." in md
    assert "No view was calibrated: the session stopped before its images were paired" in md
    assert "Mounting mode unknown" in md
    from handeye.report.advice import FALLBACK_ADVICE

    assert f"- {FALLBACK_ADVICE['config_error']}" in md  # nothing more precise known: the class's advice
    _assert_self_contained(paths[0].read_text(encoding="utf-8"))


def test_names_and_texts_are_escaped(synthetic, tmp_path):
    """Session names, view ids, findings and reasons come from files: HTML-escaped, Markdown cells safe."""
    from handeye.report import write_reports

    res = json.loads((synthetic["out"] / "result.json").read_text())
    res["session"]["path"] = "/data/<b>cell&3</b>"
    evil = '<img src=x onerror="alert(1)">'
    res["diagnostics"]["findings"] = [
        {
            "code": "overexposed",
            "severity": "info",
            "title": f"clipped {evil}",
            "evidence": "a | b",
            "action": "x",
            "view_ids": ["1"],
        }
    ]
    res["views"][0]["reason"] = "odd | reason"
    res["views"][0]["used"] = False
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    paths = write_reports(_folder(tmp_path, res, obs), strict=True, plots=False)
    html, md = (p.read_text(encoding="utf-8") for p in paths)
    assert "<b>cell&3</b>" not in html and "&lt;b&gt;cell&amp;3&lt;/b&gt;" in html
    assert evil not in html and "&lt;img src=x" in html
    _assert_self_contained(html)
    assert "odd \\| reason" in md and "odd | reason" not in md


def test_missing_thumbnails_and_stale_observations_do_not_break_the_report(synthetic, tmp_path):
    """A folder without thumbnails and with observations of a view not in this result: placeholders,
    and the stale view is not shown. The session is not read (it is gone)."""
    from handeye.report import write_reports

    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    obs["views"]["999"] = obs["views"]["1"]  # a view that is not in this result (stale file)
    res["session"]["path"] = str(tmp_path / "gone")
    paths = write_reports(_folder(tmp_path / "r", res, obs), formats=("md",), strict=True, plots=False)
    md = paths[0].read_text(encoding="utf-8")
    assert md.count("(image not available)") == len(res["views"]) and "| **999** |" not in md
    _markdown_ok(paths[0])


def _verdict(folder: Path, qa_text: str | None, tmp: Path):
    from handeye.report import build_report_context

    qa = None
    if qa_text is not None:
        qa = tmp / f"qa{abs(hash(qa_text))}.yaml"
        qa.write_text(qa_text)
    return build_report_context(folder, qa=qa, make_plots=False)


def test_site_thresholds_change_the_verdict_to_known_values(synthetic, tmp_path):
    from handeye.report import load_qa

    out, res = synthetic["out"], synthetic["res"]
    pe = res["refinement"]["predicted_error_mm"]
    shipped = load_qa()["checks"]
    # everything but the predicted error switched off: its check alone decides, at the limits put around it
    off = {k: {lim: None for lim in shipped[k]} for k in shipped if k != "predicted_error_mm"}
    base = {"include_diagnostics": False, "checks": off}

    def qa(warn, fail):
        d = json.loads(json.dumps(base))
        d["checks"]["predicted_error_mm"] = {"warn_above": warn, "fail_above": fail}
        return yaml.safe_dump(d)

    assert _verdict(out, qa(pe * 1.1, pe * 2.0), tmp_path)["verdict"].status == "pass"
    v = _verdict(out, qa(pe * 0.9, pe * 2.0), tmp_path)["verdict"]
    assert v.status == "warn" and [c.status for c in v.checks] == ["warn"]
    v = _verdict(out, qa(pe * 0.5, pe * 0.9), tmp_path)["verdict"]
    c = v.checks[0]
    assert v.status == "fail" and c.key == "predicted_error_mm" and c.status == "fail"
    assert c.value == pytest.approx(pe, rel=1e-6) and f"{pe * 0.9:g}" in c.why and c.action
    assert "predicted position error" in v.headline
    # the working distance of the site moves the predicted error: linear in distance for the
    # rotation part, so 3 m gives more than the refinement's own working distance
    ctx = _verdict(out, "working_distance_m: 3.0\n", tmp_path)
    assert ctx["result"]["working_distance_m"] == 3.0 and ctx["result"]["pred"]["rms_mm"] > pe
    # the coverage grid of the site: one cell is reached by any corner (coverage 1), and a grid as fine
    # as the pixels is reached only where corners are (at most corners / pixels)
    cov = {}
    for cells in (1, int(res["intrinsics"]["image_size"][0])):
        v = _verdict(out, f"coverage_grid_cells_x: {cells}\n", tmp_path)["verdict"]
        cov[cells] = next(c.value for c in v.checks if c.key == "image_coverage")
    n_corners = sum(v["n_corners"] for v in res["views"] if v["used"])
    w, h = res["intrinsics"]["image_size"]
    assert cov[1] == 1.0 and 0 < cov[w] <= n_corners / (w * h)


def test_evaluate_levels_and_missing_values():
    """QA levels on plain numbers: above/below limits, the stricter level first, a missing value."""
    from handeye.report.qa import evaluate

    cfg = {
        "missing_value": "warn",
        "checks": {
            "reprojection_rms_px": {"warn_above": 0.8, "fail_above": 1.5},
            "used_views": {"warn_below": 10, "fail_below": 6},
            "predicted_error_mm": {"warn_above": 2.0, "fail_above": 5.0},
        },
    }
    st = lambda m: {c.key: c.status for c in evaluate(m, cfg).checks}  # noqa: E731
    assert st({"reprojection_rms_px": 0.5, "used_views": 12, "predicted_error_mm": 1.0}) == {
        "reprojection_rms_px": "pass",
        "used_views": "pass",
        "predicted_error_mm": "pass",
    }
    assert st({"reprojection_rms_px": 1.0, "used_views": 8, "predicted_error_mm": 6.0}) == {
        "reprojection_rms_px": "warn",
        "used_views": "warn",
        "predicted_error_mm": "fail",
    }
    assert st({"reprojection_rms_px": 2.0, "used_views": 5, "predicted_error_mm": None}) == {
        "reprojection_rms_px": "fail",
        "used_views": "fail",
        "predicted_error_mm": "warn",
    }
    assert evaluate({"reprojection_rms_px": 1.0}, cfg).status == "warn"
    assert evaluate({"reprojection_rms_px": 1.0}, {**cfg, "missing_value": "pass"}).status == "warn"


def test_a_value_that_crossed_its_limit_never_reads_as_the_limit():
    from handeye.report.qa import evaluate

    cfg = {"checks": {"max_rotation_deg": {"warn_below": 30.0}, "reprojection_rms_px": {"warn_above": 0.8}}}
    v = evaluate({"max_rotation_deg": 29.97, "reprojection_rms_px": 0.8004}, cfg)
    c = {c.key: c for c in v.checks}
    assert c["max_rotation_deg"].value_text == "29.97 deg" and "29.97 deg < 30.0 deg" in v.headline
    assert "at most 29.97 deg" in c["max_rotation_deg"].why
    assert c["reprojection_rms_px"].value_text.startswith("0.8004")  # as many decimals as it takes
    assert evaluate({"max_rotation_deg": 25.04}, cfg).checks[0].value_text == "25.0 deg"  # else as configured


def test_the_robot_error_model_is_said_in_words(synthetic):
    """The iid robot model's line read 'sigma deg: 5.73e-05; estimated: sigma_mm, sigma_deg; resolved: rot: True;
    trans: False' (result.json's keys and Python's booleans)."""
    md = (synthetic["out"] / "report.md").read_text(encoding="utf-8")
    line = next(x for x in md.splitlines() if x.startswith("Robot error model:"))
    assert "sigma per axis and view:" in line and " mm / " in line, line
    assert not re.search(r"True|False|sigma_mm|sigma_deg|resolved:|estimated:", line), line


def test_a_small_value_is_not_printed_as_zero():
    """A sigma of 0.003 mm at two decimals read "0.00 mm" (a single marker's predicted error, its headline)."""
    from handeye.report.formatting import num

    assert [num(v) for v in (0.0034, -0.0003, 0.02, 0.0, 1.234)] == ["0.0034", "-0.00030", "0.02", "0.00", "1.23"]
    assert num(3e-8) == "3.0e-08" and num(0.0034, 3) == "0.003" and num(0.0004, 2, signed=True) == "+0.00040"


def test_a_failing_finding_fails_the_verdict_and_its_numbers_are_not_shown_green(synthetic, tmp_path):
    from handeye.report import build_report_context

    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    res["diagnostics"]["findings"] = [
        {
            "code": "translation_units",
            "severity": "fail",
            "title": "Robot translations are in millimetres, read as metres",
            "evidence": "...",
            "action": "set translation_unit: mm",
            "view_ids": [],
        }
    ]
    ctx = build_report_context(_folder(tmp_path, res, obs), make_plots=False)
    assert ctx["verdict"].status == "fail" and "millimetres" in ctx["verdict"].headline
    assert "Predicted position error" not in ctx["verdict"].headline  # a distrusted number is not headlined
    cards = {k["label"].split(" at ")[0]: k for k in ctx["kpis"]}
    assert cards["Predicted error"]["status"] == "untrusted"
    assert cards["Rotation coverage"]["status"] == "untrusted"
    assert cards["Views used"]["status"] != "untrusted"  # the finding says nothing about the view count
    assert all(k["status"] != "pass" for k in ctx["kpis"] if k["label"].startswith(("Predicted", "Rotation")))
    # in the checks table too: the numbers it distrusts are not "passed"
    status = {c.key: c.status for c in ctx["verdict"].checks}
    assert status["predicted_error_mm"] == "untrusted" and status["max_rotation_deg"] == "untrusted"
    res["diagnostics"]["findings"] = []
    before = {
        c.key: c.status for c in build_report_context(_folder(tmp_path, res, obs), make_plots=False)["verdict"].checks
    }
    from handeye.report.advice import UNTRUSTED_METRICS

    distrusted = set(UNTRUSTED_METRICS["translation_units"])
    assert {k: v for k, v in status.items() if k not in distrusted} == {
        k: v for k, v in before.items() if k not in distrusted
    }  # the other checks are as they were
    assert {status[k] for k in distrusted if before[k] == "pass"} == {"untrusted"}
    assert ctx["verdict"].counts["pass"] == sum(s == "pass" for s in status.values())


def test_a_wrong_square_size_distrusts_the_translation_uncertainty_and_the_headline_skips_it(synthetic, tmp_path):
    """A wrong square size scales X's translation and its sigma: the failing translation checks are shown
    untrusted (fix the size first) and the headline names the size, not their numbers."""
    from handeye.report import build_report_context

    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    res["diagnostics"]["findings"] = [
        {
            "code": "square_size",
            "severity": "fail",
            "title": "The board's squares look like 26.8 mm, not 23.6 mm",
            "evidence": "...",
            "action": "state L: 0.0268",
            "view_ids": [],
            "details": {"measured_mm": 26.8, "stated_mm": 23.6},
        }
    ]
    qa = tmp_path / "qa.yaml"  # a limit the synthetic result's translation sigma fails
    qa.write_text("checks:\n  sigma_trans_mm: {warn_above: 0.00001, fail_above: 0.00002}\n")
    ctx = build_report_context(_folder(tmp_path, res, obs), make_plots=False, qa=qa)
    status = {c.key: c.status for c in ctx["verdict"].checks}
    assert status["sigma_trans_mm"] == "untrusted" and status["predicted_error_mm"] == "untrusted"
    head = ctx["verdict"].headline
    assert head.startswith("Squares look like 26.8 mm, not 23.6 mm") and "translation uncertainty" not in head


def _with_stages(res: dict, *, findings=None, crashed=None, skipped=None) -> dict:
    """``res`` with its diagnostics' stage record replaced: every stage ok, except ``crashed``
    ({name: error}) and ``skipped`` ({name: why}), as handeye.diagnose.findings.Stages writes it."""
    res = json.loads(json.dumps(res))
    d = res["diagnostics"]
    crashed, skipped = crashed or {}, skipped or {}
    d["stages"] = {n: ("crashed" if n in crashed else "skipped" if n in skipped else "ok") for n in d["stages"]}
    d["stage_errors"], d["stages_skipped"], d["crashed_stages"] = dict(crashed), dict(skipped), len(crashed)
    if findings is not None:
        d["findings"] = findings
    return res


def _reports(folder: Path) -> tuple[str, str]:
    """(report.md, the visible text of report.html) written from ``folder`` without figures."""
    from handeye.report import write_reports

    write_reports(folder, strict=True, plots=False)
    html = (folder / "report.html").read_text(encoding="utf-8")
    text = html_lib.unescape(re.sub(r"<[^>]+>", " ", html.split("<body>")[1]))
    return (folder / "report.md").read_text(encoding="utf-8"), " ".join(text.split())


def test_a_crashed_diagnostics_stage_is_shown_and_counts_in_the_verdict(synthetic, tmp_path):
    """A stage that crashed is named with its error, the report never says the dataset has nothing
    wrong, and the verdict is at least WARN (configs/qa.yaml crashed_stage), even with the
    diagnostics' findings switched off and every other check passing."""
    from handeye.report import build_report_context, load_qa

    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    assert res["diagnostics"]["crashed_stages"] == 0 and res["diagnostics"]["stages"]["images"] == "ok"
    shipped = load_qa()["checks"]
    off = yaml.safe_dump(
        {"include_diagnostics": False, "checks": {k: {lim: None for lim in shipped[k]} for k in shipped}}
    )
    error = "ValueError: operands could not be broadcast together with shapes (3,) (4,)"

    clean = _folder(tmp_path / "clean", _with_stages(res, findings=[]), obs)
    crashed = _folder(tmp_path / "crashed", _with_stages(res, findings=[], crashed={"images": error}), obs)
    assert _verdict(clean, off, tmp_path)["verdict"].status == "pass"  # the control: nothing else counts
    v = _verdict(crashed, off, tmp_path)["verdict"]
    assert v.status == "warn" and [(c.key, c.status, c.value) for c in v.checks] == [
        ("diagnostics_stages", "warn", 1.0)
    ]
    assert "diagnostics stage images crashed" in v.headline and error in v.checks[0].why
    v = _verdict(crashed, off + "crashed_stage: fail\n", tmp_path)["verdict"]
    assert v.status == "fail" and v.checks[0].status == "fail"
    ctx = build_report_context(crashed, make_plots=False)
    assert ctx["stages"]["crashed"] == [{"name": "images", "checks": "image blur and exposure", "error": error}]
    assert ctx["verdict"].status in ("warn", "fail")  # shipped thresholds: never PASS with a crash

    md, html = _reports(crashed)
    for text in (md, html):
        assert "nothing wrong" not in text
        assert "1 diagnostics stage crashed: its checks did not run" in text
        assert "No findings from the checks that ran, but 1 stage crashed" in text
        assert text.count(error) >= 2  # in the crash notice, the checks table and the list of checks not run
    assert "- **CRASHED** `images`: image blur and exposure — `" + error + "`" in md
    assert "CRASHED images : image blur and exposure — " + error in html

    # two crashed stages with a finding left: both named, the finding still shown
    two = _with_stages(res, crashed={"images": error, "coverage": "KeyError: 'n_corners'"})
    md, html = _reports(_folder(tmp_path / "two", two, obs))
    assert "2 diagnostics stages crashed: their checks did not run" in md and "KeyError: 'n_corners'" in html
    assert "nothing wrong" not in md and "nothing wrong" not in html


def test_diagnostics_that_did_not_all_run_never_claim_nothing_wrong(synthetic, tmp_path):
    """No findings: "nothing wrong" only when every stage ran; a skipped stage is named with why."""
    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    n = len(res["diagnostics"]["stages"])
    md, html = _reports(_folder(tmp_path / "clean", _with_stages(res, findings=[]), obs))
    claim = f"The diagnostics found nothing wrong with this dataset (all {n} stages ran)."
    assert claim in md and claim in html and "did not run" not in md
    skipped = _with_stages(res, findings=[], skipped={"cross_validation": "not asked for"})
    md, html = _reports(_folder(tmp_path / "skipped", skipped, obs))
    assert "nothing wrong with this dataset (" not in md and "nothing wrong with this dataset (" not in html
    assert "The checks that ran found nothing wrong with this dataset; some checks did not run" in md
    assert "- **SKIPPED** `cross_validation`: validation on held-out views — not asked for" in md
    assert "SKIPPED cross_validation : validation on held-out views — not asked for" in html
    # a result written before the stages were recorded does not claim that everything ran
    old = json.loads(json.dumps(res))
    for k in ("stages", "stage_errors", "stages_skipped", "crashed_stages"):
        old["diagnostics"].pop(k)
    old["diagnostics"]["findings"] = []
    md, _ = _reports(_folder(tmp_path / "old", old, obs))
    assert "nothing wrong" not in md and "does not record which of their checks ran" in md


def test_bad_site_qa_file_is_a_one_line_error(synthetic, tmp_path):
    from handeye.cli import main
    from handeye.errors import ConfigError
    from handeye.report import load_qa

    bad = tmp_path / "bad.yaml"
    bad.write_text("checks:\n  reprojection_rms_px: {warn_over: 1}\n")
    with pytest.raises(ConfigError, match="warn_over"):
        load_qa(bad)
    bad.write_text("coverage_grid_cells_x: 0\n")
    with pytest.raises(ConfigError, match="coverage_grid_cells_x"):
        load_qa(bad)
    bad.write_text("crashed_stage: info\n")  # a crashed stage never counts as less than warn
    with pytest.raises(ConfigError, match="crashed_stage"):
        load_qa(bad)
    bad.write_text("no_such_setting: 1\n")
    with pytest.raises(ConfigError, match="no_such_setting"):
        load_qa(bad)
    assert main(["-q", "report", str(synthetic["out"]), "--qa", str(bad)]) == ConfigError.exit_code


def test_report_command_rebuilds_from_the_folder_alone(synthetic, tmp_path, capsys):
    """handeye report on a copy of the result folder, the session moved away: same thumbnails, the
    verdict of the site thresholds."""
    from handeye.cli import main

    copy = tmp_path / "copy"
    shutil.copytree(synthetic["out"], copy)
    session, hidden = synthetic["session"], tmp_path / "session_moved"
    shutil.move(session, hidden)
    try:
        qa = tmp_path / "qa.yaml"
        qa.write_text("checks:\n  reprojection_rms_px: {warn_above: 0.0001, fail_above: 0.0002}\n")
        dest = tmp_path / "rebuilt"
        assert main(["-q", "report", str(copy), "--qa", str(qa), "--out", str(dest)]) == 0
    finally:
        shutil.move(hidden, session)
    md = (dest / "report.md").read_text(encoding="utf-8")
    assert "## Verdict: **FAIL**" in md and "Reprojection RMS" in md
    assert "report.md" in capsys.readouterr().out
    n = len(list((copy / "thumbnails").glob("*.jpg")))
    assert n > 0 and len(list((dest / "report_files").glob("view_*.jpg"))) == n
    assert _images_decode((dest / "report.html").read_text(encoding="utf-8"))["jpeg"] == n


def test_matplotlib_and_jinja_load_only_when_a_report_is_written(synthetic):
    """The calibrate command and a report without figures do not pay for matplotlib (or jinja2 for a context)."""
    import sys

    code = (
        "import sys; from handeye.report import build_report_context; import handeye.cli; "
        "build_report_context(sys.argv[1], make_plots=False); "
        "print(','.join(m for m in ('matplotlib', 'jinja2', 'PIL') if m in sys.modules))"
    )
    p = subprocess.run([sys.executable, "-c", code, str(synthetic["out"])], capture_output=True, text=True, check=True)
    assert p.stdout.strip() == "", p.stdout


def test_calibrate_without_a_report_loads_no_drawing_and_no_scipy(synthetic, tmp_path):
    """``calibrate --no-report`` imports only what it uses.

    No matplotlib or jinja2 (nothing is drawn or rendered) and no scipy (start-up costs of every run; the
    tails of the tests are handeye.special's), while it writes the same result.json as the run with the reports.
    """
    import sys

    out = tmp_path / "no_report"
    code = (
        "import sys, handeye.cli; rc = handeye.cli.main(sys.argv[1:]); "
        "print(','.join(sorted({m.split('.')[0] if m.split('.')[0] != 'scipy' else '.'.join(m.split('.')[:2]) "
        "for m in sys.modules if m.split('.')[0] in ('matplotlib', 'jinja2', 'scipy')} | "
        "({'handeye.special'} & set(sys.modules)))), rc)"
    )
    p = subprocess.run(
        [sys.executable, "-c", code, "-q", "calibrate", str(synthetic["session"]), "--out", str(out), "--no-report"],
        capture_output=True,
        text=True,
        check=True,
    )
    loaded = p.stdout.strip().splitlines()[-1].split()[0].split(",")
    assert not any(m.split(".")[0] in ("matplotlib", "jinja2", "scipy") for m in loaded), loaded
    assert "handeye.special" in loaded  # the refinement's tail probabilities: the check above is on a real run
    before = json.loads((synthetic["out"] / "result.json").read_text())
    after = json.loads((out / "result.json").read_text())
    assert after["verdict"] == before["verdict"] and after["n_views"] == before["n_views"]
    np.testing.assert_allclose(after["hand_eye"]["matrix"], before["hand_eye"]["matrix"], atol=1e-9)
    assert not (out / "report.html").exists()


def test_figures_drawn_in_two_processes_are_the_same_pngs(synthetic, monkeypatch):
    """The report's six figures drawn by this process and a forked child are byte for byte the ones drawn here."""
    import sys

    from handeye.report import build_report_context, figures

    if not sys.platform.startswith("linux"):
        pytest.skip("the forked drawing is Linux only")
    ctx = build_report_context(synthetic["out"], make_plots=False)
    monkeypatch.setattr(figures, "parallel_drawing", lambda: True)
    two = figures.report_figures(**ctx["figure_inputs"])
    monkeypatch.setattr(figures, "parallel_drawing", lambda: False)
    one = figures.report_figures(**ctx["figure_inputs"])
    assert [p.key for p in two] == ["residuals", "per_view", "coverage", "poses", "rotations", "uncertainty"]
    assert [(p.key, p.title, p.caption, p.png) for p in two] == [(p.key, p.title, p.caption, p.png) for p in one]


def test_pose_figure_draws_both_mounting_modes():
    """The pose figure for a moving camera (eye-in-hand) and a moving board (eye-to-hand), flagged views
    included: a PNG of the figure's size (8.6 x 4.2 in at 100 dpi)."""
    import cv2

    from handeye.frames import T_from_rotvec
    from handeye.report import plots

    rng = np.random.default_rng(1)
    T_be = np.stack([T_from_rotvec(rng.normal(size=3) * 0.3, [0.4, 0.1 * k, 0.5]) for k in range(6)])
    T_x = T_from_rotvec([0.1, 0.2, 0.3], [0.01, 0.02, 0.05])
    outline = np.array([[0, 0, 0], [0.2, 0, 0], [0.2, 0.15, 0], [0, 0.15, 0]], float)
    flagged = [False, True, False, False, False, False]
    with plots.style():
        for moves in (True, False):
            cams = T_be @ T_x if moves else np.repeat(T_x[None], 6, axis=0)
            boards = np.repeat(T_x[None], 6, axis=0) if moves else T_be @ T_x
            png = plots.poses_3d(
                T_base_cams=cams,
                T_base_ends=T_be,
                T_base_boards=boards,
                board_outline=outline,
                flagged=flagged,
                camera_moves=moves,
            )
            img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
            assert img.shape == (420, 860, 3) and float(img.std()) > 10


def test_pose_figure_legend_sits_under_both_views_not_over_the_poses(monkeypatch):
    """The legend is the figure's, in one row below both views: inside a view it covered poses near its corner."""
    from handeye.frames import T_from_rotvec
    from handeye.report import plots
    from handeye.report.plots import geometry

    drawn = []
    monkeypatch.setattr(geometry, "_png", lambda fig: drawn.append(fig) or b"")
    T_be = np.stack([T_from_rotvec([0.1 * k, 0.2, 0.0], [0.3 + 0.1 * k, 0.25, 0.5]) for k in range(6)])
    T_x = T_from_rotvec([0.1, 0.2, 0.3], [0.01, 0.02, 0.05])
    outline = np.array([[0, 0, 0], [0.2, 0, 0], [0.2, 0.15, 0], [0, 0.15, 0]], float)
    with plots.style():
        plots.poses_3d(
            T_base_cams=T_be @ T_x,
            T_base_ends=T_be,
            T_base_boards=np.repeat(T_x[None], 6, axis=0),
            board_outline=outline,
            flagged=[True] + [False] * 5,
            camera_moves=True,
        )
    (fig,) = drawn
    fig.canvas.draw()
    assert all(ax.get_legend() is None for ax in fig.axes)
    (legend,) = fig.legends
    box = legend.get_window_extent()
    labels = [t.get_text() for t in legend.get_texts()]
    assert labels == ["robot end (flange), x y z", "camera", "board", "dropped view"]
    assert all(box.y1 < ax.get_window_extent().y0 for ax in fig.axes)


@pytest.mark.realdata
def test_clean_real_dataset_is_not_reported_as_failed(tmp_path, shared_dataset):
    from handeye.session.importers import import_ical

    real = shared_dataset("ical-mako-charuco-eye-to-hand")
    session = import_ical(real, tmp_path / "session")
    wf = calibrate_session(
        Path(session).parent, options=CalibrateOptions(refine=False), out_dir=tmp_path / "out", diagnostics=False
    )
    md = (tmp_path / "out" / "report.md").read_text(encoding="utf-8")
    assert wf.status == "ok" and "## Verdict: **FAIL**" not in md
    assert "| **2** |" in md and "dropped" in md  # the one view with too few corners
    _markdown_ok(tmp_path / "out" / "report.md")


# ------------------------------------------------------------------------------ the banner's root cause
ROOT_CAUSE_FINDINGS = [
    (
        {
            "code": "mode_swapped",
            "severity": "fail",
            "title": "The data are eye-to-hand but were calibrated as eye-in-hand",
            "action": "calibrate with --mode eye_to_hand",
        },
        "Mode swapped: the data are eye-to-hand but were calibrated as eye-in-hand. ",
    ),
    (
        {
            "code": "board_moved",
            "severity": "fail",
            "title": "The board slipped in the gripper after view 6",
            "action": "clamp the board",
            "details": {"split_after_view": "6"},
        },
        "The board slipped in the gripper after view 6. ",
    ),
    (
        {
            "code": "square_size",
            "severity": "fail",
            "title": "The board's squares look like 30.0 mm, not 25 mm",
            "action": "measure the squares",
            "details": {"measured_mm": 30.04, "stated_mm": 25.0},
        },
        "Squares look like 30.0 mm, not 25 mm. ",
    ),
    (
        {
            "code": "pairs_shifted",
            "severity": "fail",
            "title": "Images and robot poses are out of step by 1: image k belongs to pose k+1",
            "action": "re-pair the poses",
            "details": {"shift": 1},
        },
        "Pairs shifted by one line: images and robot poses are out of step by 1: image k belongs to pose k+1. ",
    ),
]


@pytest.mark.parametrize("finding, lead", ROOT_CAUSE_FINDINGS, ids=[f["code"] for f, _ in ROOT_CAUSE_FINDINGS])
def test_the_banner_leads_with_the_root_cause_of_a_failing_finding(synthetic, tmp_path, finding, lead):
    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    other = {"code": "blurred", "severity": "fail", "title": "Blurred images: 2 view(s)", "action": "refocus"}
    res["diagnostics"]["findings"] = [other, dict(finding, evidence="...", view_ids=[])]
    folder = _folder(tmp_path, res, obs)
    from handeye.report import build_report_context

    ctx = build_report_context(folder, make_plots=False)
    assert ctx["verdict"].status == "fail" and ctx["verdict_label"] == "FAIL"
    assert ctx["verdict"].headline.startswith(lead), ctx["verdict"].headline
    assert "blurred images: 2 view(s)" in ctx["verdict"].headline  # the other finding still named, after it
    assert ctx["verdict"].headline.lower().count(finding["title"].lower()) <= 1  # the cause is not named twice
    assert ctx["verdict"].headline.count(" fails QA: blurred images: 2 view(s).") == 1
    md, _ = _reports(folder)
    assert f"> **FAIL** — {lead}" in md


def test_a_warning_does_not_lead_a_failed_banner(synthetic, tmp_path):
    from handeye.report import build_report_context

    res = json.loads((synthetic["out"] / "result.json").read_text())
    res["diagnostics"]["findings"] = [
        {"code": "mode_undecided", "severity": "warn", "title": "The session states no mounting mode", "action": ""},
        {"code": "blurred", "severity": "fail", "title": "Blurred images: 2 view(s)", "action": "refocus"},
    ]
    ctx = build_report_context(_folder(tmp_path / "f", res), make_plots=False)
    assert ctx["verdict"].headline.startswith("T_end_cam fails QA: blurred images")
    res["diagnostics"]["findings"] = res["diagnostics"]["findings"][:1]
    ctx = build_report_context(_folder(tmp_path / "w", res), make_plots=False)
    assert ctx["verdict"].status == "warn"
    assert ctx["verdict"].headline.startswith(
        "Mounting mode not decided: the session states no mounting mode. T_end_cam passes"
    )


REFUSALS = [
    (
        "mode_swapped",
        "the data are eye_to_hand but --mode says eye_in_hand: fits 12x better",
        "calibrate with --mode eye_to_hand (or set mode: eye_to_hand in the session)",
        "Mode swapped: the data are eye_to_hand but --mode says eye_in_hand: fits 12x better. Fix: calibrate with "
        "--mode eye_to_hand (or set mode: eye_to_hand in the session). No result is given.",
    ),
    (
        "pairs_shifted",
        "Images and robot poses are out of step by 2: image k belongs to pose k+2: ...",
        "fix the pairing, or apply the shift with --shift-poses 2 (image k takes pose line k+2)",
        "Pairs shifted by 2 lines: images and robot poses are out of step by 2: image k belongs to pose k+2. Fix: "
        "fix the pairing, or apply the shift with --shift-poses 2 (image k takes pose line k+2). No result is given.",
    ),
    (
        "pairs_shuffled",
        "Images and robot poses are shuffled: 6 of 12 images carry another view's pose: ...",
        "re-pair images and poses by view id",
        "Pairs shuffled: 6 of 12 images "
        "carry another view's pose. Fix: re-pair images and poses by view id. No result is given.",
    ),
]


@pytest.mark.parametrize("code, what, fix, headline", REFUSALS, ids=[r[0] for r in REFUSALS])
def test_a_refused_run_leads_with_its_cause_and_fix(tmp_path, code, what, fix, headline):
    from handeye.report import build_report_context

    findings = []
    if code == "pairs_shifted":
        findings = [
            {
                "code": "pairs_shifted",
                "severity": "fail",
                "title": "Images and robot poses are out of step by 2: image k belongs to pose k+2",
                "action": "re-pair",
                "details": {"shift": 2},
            }
        ]
    if code == "pairs_shuffled":
        findings = [
            {
                "code": "pairs_shuffled",
                "severity": "fail",
                "title": "Images and robot poses are shuffled: 6 of 12 images carry another view's pose",
                "action": "re-pair",
                "details": {},
            }
        ]
    res = {
        "status": "failed",
        "verdict": "REFUSED",
        "mode": "eye_in_hand",
        "views": [],
        "failure_reason": what,
        "diagnostics": {"findings": findings},
        "error": {
            "code": code,
            "type": "SessionRefused",
            "what": what,
            "file": None,
            "line": None,
            "expected": None,
            "got": None,
            "fix": fix,
        },
    }
    folder = _folder(tmp_path, res)
    ctx = build_report_context(folder, make_plots=False)
    assert ctx["verdict_label"] == "REFUSED" and ctx["verdict"].headline == headline
    md, text = _reports(folder)
    assert f"> **REFUSED** — {headline}" in md and "REFUSED" in text.split("Verdict")[1][:200]


def test_a_failed_run_without_a_known_cause_keeps_its_headline(failed):
    from handeye.report import build_report_context

    ctx = build_report_context(failed["out"], make_plots=False)
    assert ctx["root_cause"] is None and ctx["verdict_label"] == "FAIL"
    assert ctx["verdict"].headline.startswith("The session could not be calibrated. ")


# ------------------------------------------------------------------------------ advice for the new codes
def test_advice_for_the_new_finding_and_refusal_codes(tmp_path):
    from handeye.report import build_report_context
    from handeye.report.advice import ERROR_ADVICE, FINDING_ADVICE, finding_advice

    assert "caliper" in FINDING_ADVICE["square_size"] and "metres" in FINDING_ADVICE["square_size"]
    assert "paired" in FINDING_ADVICE["poses_do_not_fit"] and "mounting mode" in FINDING_ADVICE["poses_do_not_fit"]
    assert "--mode" in FINDING_ADVICE["mode_undecided"]
    assert "--mode" in ERROR_ADVICE["mode_swapped"] and "eye_to_hand" in ERROR_ADVICE["mode_swapped"]
    assert "--shift-poses N" in ERROR_ADVICE["pairs_shifted"]
    assert "view id" in ERROR_ADVICE["pairs_shuffled"]
    assert all(FINDING_ADVICE[c] == ERROR_ADVICE[c] for c in ("mode_swapped", "pairs_shifted", "pairs_shuffled"))
    # keyed on the code, never on the text: a title that reads like another finding gets its code's advice
    f = {"code": "square_size", "title": "The mounting mode is not decided", "action": ""}
    assert finding_advice(f) == FINDING_ADVICE["square_size"]
    assert finding_advice({"code": "blurred", "title": "squares look like 30 mm"}) == ""
    for code in ("mode_swapped", "pairs_shifted", "pairs_shuffled"):
        res = {
            "status": "failed",
            "mode": "eye_in_hand",
            "views": [],
            "failure_reason": "x",
            "error": {"code": code, "type": "SessionRefused", "what": "refused", "fix": None},
        }
        f = build_report_context(_folder(tmp_path / code, res), make_plots=False)["failure"]
        assert ERROR_ADVICE[code] in f["actions"]


def test_the_findings_section_shows_the_advice_of_the_code(synthetic, tmp_path):
    from handeye.report.advice import FINDING_ADVICE

    res = json.loads((synthetic["out"] / "result.json").read_text())
    res["diagnostics"]["findings"] = [
        {
            "code": "poses_do_not_fit",
            "severity": "fail",
            "title": "The robot poses do not fit the images as read",
            "evidence": "...",
            "action": "check",
            "view_ids": [],
        }
    ]
    md, text = _reports(_folder(tmp_path, res))
    assert f"Check: {FINDING_ADVICE['poses_do_not_fit']}" in md
    assert f"Check: {FINDING_ADVICE['poses_do_not_fit']}" in text


# ------------------------------------------------------------------------------ flagged views
def test_views_with_flagged_corners_are_listed_but_not_counted_as_dropped(synthetic, tmp_path):
    """The dropped/flagged share counts the views that did not serve X (dropped, robot pose excluded); a used
    view with a few outlier corners is listed with them, once, and not counted (retaking it would not help)."""
    from handeye.report import build_report_context

    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    res["refinement"]["outliers"] = []
    for v in res["views"]:
        v["flags"] = []
    base = build_report_context(_folder(tmp_path / "a", res, obs), make_plots=False)
    n_base = sum(v["flagged"] for v in base["views"])
    assert n_base == sum(v["status"] != "used" for v in base["views"]) > 0
    clean = [v for v in res["views"] if v["used"]][:2]
    clean[0]["flags"] = ["corners 3, 7: reprojection 4.1 px > 3.0 px"]
    clean[1]["flags"] = ["corner 2: reprojection 5.0 px", "corner 9: reprojection 3.5 px"]  # still one view
    ctx = build_report_context(_folder(tmp_path / "b", res, obs), make_plots=False)
    rows = {v["id"]: v for v in ctx["views"]}
    for v in clean:
        row = rows[str(v["id"])]
        assert row["status"] == "used" and row["corner_flags"] and not row["flagged"]
    assert sum(v["flagged"] for v in ctx["views"]) == n_base
    assert sum(v["corner_flags"] for v in ctx["views"]) == 2
    card = next(k for k in ctx["kpis"] if k["label"] == "Views used")
    assert card["sub"] == f"{n_base} dropped; 2 used with outlier corners"
    share = next(c for c in ctx["verdict"].checks if c.key == "dropped_share")
    assert share.value == pytest.approx(n_base / len(ctx["views"]))


def test_a_kinematic_robot_model_is_summarised_with_its_dh_prior_test():
    """The report names the kinematic model's arm, encoder noise and DH prior: the stated one, the one used and
    the test between them, and the largest DH offsets; the DH table and every view's joint angles stay in
    result.json."""
    from handeye.report.context import _robot_model

    off = np.zeros((6, 4))
    off[4, 0], off[3, 1] = 2.36, -0.464
    rm = {
        "kind": "kinematic",
        "arm": "UR3e",
        "dh_convention": "standard",
        "description": "DH offsets and encoder noise",
        "dh_table": {"links": [{"a": 0.0}] * 6},
        "joint_angles": "recorded",
        "joint_angles_rad": {str(i): [0.1 * i] * 6 for i in range(1, 41)},
        "encoder_sigma_deg": 0.0943,
        "encoder_sigma_resolved": True,
        "estimated": ["dh_offset", "encoder_sigma_deg"],
        "dh_offset": off.tolist(),
        "dh_offset_sigma": np.full((6, 4), 0.1).tolist(),
        "dh_resolved_share": np.r_[np.ones(15), np.zeros(9)].reshape(6, 4).tolist(),
        "dh_prior": "the arm's error prior",
        "dh_prior_sigma": {"length_mm": 1.774, "angle_deg": 0.1774},
        "dh_prior_sigma_stated": {"length_mm": 0.5, "angle_deg": 0.05},
        "dh_prior_scale": 3.548,
        "dh_prior_test": {
            "resolved": True,
            "statistic": 33.33,
            "redundancy": 8.04,
            "dof": 11.98,
            "p_value": 1.6e-6,
            "alpha": 0.01,
            "contradicted": True,
        },
        "tool_offset_T_flange_reported": np.eye(4).tolist(),
        "tool_offset_spread_deg_mm": [1e-14, 1e-13],
        "joints_disagree_view_ids": ["7"],
    }
    items = {it["name"]: it["value"] for it in _robot_model({"robot_model": rm})["items"]}
    assert items["arm"] == "UR3e (standard DH)" and items["joint angles"] == "recorded"
    assert items["encoder noise"].startswith("0.0943 deg") and "estimated" in items["encoder noise"]
    dh = items["DH prior"]
    assert dh.startswith("1.77 mm / 0.177 deg") and "stated 0.5 mm / 0.05 deg" in dh and "p = 1.6e-06" in dh
    assert "chi-square 33.3 with 8.0 offsets resolved" in dh
    assert "x3.55" in dh
    assert "+2.36" in items["DH offsets"] and "a of joint 5" in items["DH offsets"]
    assert "alpha of joint 4" in items["DH offsets"] and "15 of 24 known more from the views" in items["DH offsets"]
    assert items["joints disagree with the pose"] == "7"
    text = " ".join(items.values())
    assert "joint angles rad" not in items and "links" not in text and "0.4, 0.4" not in text
    rm.update(
        dh_prior_scale=1.0,
        dh_prior_sigma=rm["dh_prior_sigma_stated"],
        dh_prior_test={
            "resolved": True,
            "statistic": 9.1,
            "redundancy": 12.0,
            "p_value": 0.69,
            "alpha": 0.01,
            "contradicted": False,
        },
        joints_disagree_view_ids=[],
    )
    items = {it["name"]: it["value"] for it in _robot_model({"robot_model": rm})["items"]}
    assert items["DH prior"] == (
        "0.5 mm / 0.05 deg per DH parameter, the arm's stated prior (not rejected at 1 %: p = 0.69)"
    )
    assert "joints disagree with the pose" not in items
    rm.update(dh_prior="an earlier calibration's estimate", dh_prior_test={})
    items = {it["name"]: it["value"] for it in _robot_model({"robot_model": rm})["items"]}
    assert items["DH prior"] == "an earlier calibration's estimate (the arm's own: 0.5 mm / 0.05 deg per DH parameter)"


def test_the_offset_explanation_names_what_the_robot_model_cannot_see():
    """A result far from every closed form: the explanation's advice depends on the robot model used (the
    kinematic model is not advised to a run that used it)."""
    from handeye.report.uncertainty import offset_explanation

    rows = [
        {
            "name": m,
            "kind": "closed_form",
            "d_mm": 20.0 + k,
            "d_deg": 1.5,
            "sigma": 9.0 + k,
            "offset_mm": [20.0 + k, 0.0, 0.0],
        }
        for k, m in enumerate(("tsai", "park", "horaud"))
    ]
    rows += [
        {"name": h, "kind": "half", "d_mm": 1.0, "d_deg": 0.1, "sigma": 1.0, "offset_mm": [1.0, 0, 0]}
        for h in ("odd", "even")
    ]
    kw = dict(limit_sigma=4.0, halves_m2=3.0, halves_m2_limit=16.8, robot_mm=0.8, robot_deg=0.2)
    iid = " ".join(offset_explanation(rows, robot_model="iid", **kw))
    kin = " ".join(offset_explanation(rows, robot_model="kinematic", **kw))
    assert "each half of the views, refitted alone, lands within 1.0 σ" in iid
    assert "calibrate with the arm's kinematic model (--robot ARM)" in iid
    assert "--robot" not in kin and "beyond its DH offsets and encoder noise" in kin


def test_each_figure_gets_its_own_qa_limits(synthetic, tmp_path, monkeypatch):
    """The per-view figure draws the reprojection limits and the rotation figure the rotation limits (each
    figure's limits bound when it is planned, not the last ones looked up)."""
    import handeye.report.plots as plots
    from handeye.report import build_report_context
    from handeye.report.qa import load_qa

    monkeypatch.setenv("HANDEYE_FIGURE_PROCESSES", "1")  # the spies record in this process
    got = {}
    for name in ("per_view_bars", "rotation_coverage"):
        real = getattr(plots, name)

        def spy(*a, _real=real, _name=name, **k):
            got[_name] = k
            return _real(*a, **k)

        monkeypatch.setattr(plots, name, spy)
    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    build_report_context(_folder(tmp_path / "f", res, obs), make_plots=True)
    checks = load_qa()["checks"]
    assert (got["per_view_bars"]["warn_px"], got["per_view_bars"]["fail_px"]) == (
        checks["reprojection_rms_px"]["warn_above"],
        checks["reprojection_rms_px"]["fail_above"],
    )
    assert (got["rotation_coverage"]["warn_deg"], got["rotation_coverage"]["fail_deg"]) == (
        checks["max_rotation_deg"]["warn_below"],
        checks["max_rotation_deg"]["fail_below"],
    )


def test_nulls_in_the_validation_block_and_deleted_images_do_not_break_or_inflate_the_report(synthetic, tmp_path):
    """A NaN stored as null in the diagnostics' validation prints as a dash; a pose line whose image was deleted
    is listed as dropped but is not counted in the dropped share (nothing was captured badly)."""
    from handeye.report import build_report_context

    res = json.loads((synthetic["out"] / "result.json").read_text())
    obs = json.loads((synthetic["out"] / "observations.json").read_text())
    cv = res["diagnostics"]["cross_validation"]
    cv.update(
        verdict_sigma_rot_deg=[None, 0.01, 0.02],
        verdict_sigma_trans_mm=[None, 0.1, 0.2],
        ratio_rot_verdict=0.9,
        ratio_trans_verdict=None,
        ratio_limits=[0.5, None],
        spread_p_value=0.3,
    )
    base = build_report_context(_folder(tmp_path / "a", res, obs), make_plots=False)
    share0 = next(c for c in base["verdict"].checks if c.key == "dropped_share").value
    v = next(x for x in res["views"] if x["used"])
    v.update(used=False, reason="image file missing (pose line 3 not used)")
    res["refinement"]["per_view"].pop(str(v["id"]), None)  # the refinement never saw it
    md, _ = _reports(_folder(tmp_path / "b", res, obs))
    assert "Held-out spread / verdict σ: rotation 0.90×, translation —×" in md
    assert "Range of the ratio by chance when the model holds: 0.50-—×" in md
    ctx = build_report_context(_folder(tmp_path / "c", res, obs), make_plots=False)
    row = next(r for r in ctx["views"] if r["id"] == str(v["id"]))
    assert row["status"] == "dropped" and row["reason_kind"] == "image missing" and not row["flagged"]
    assert next(c for c in ctx["verdict"].checks if c.key == "dropped_share").value == pytest.approx(share0)
    # an image that --shift-poses leaves without a pose is listed as dropped, not counted either
    v.update(reason="no pose line after --shift-poses 1")
    ctx = build_report_context(_folder(tmp_path / "d", res, obs), make_plots=False)
    row = next(r for r in ctx["views"] if r["id"] == str(v["id"]))
    assert row["status"] == "dropped" and row["reason_kind"] == "no pose (shifted)" and not row["flagged"]
    assert next(c for c in ctx["verdict"].checks if c.key == "dropped_share").value == pytest.approx(share0)


def test_the_tracker_model_lines_of_a_pose_only_result():
    """The tracker's noise (in the noise table), its sigmas' degrees of freedom with X's factor, and an estimated
    scale."""
    from handeye.report.sections.models import _noise, _tracker

    ref = {
        "tracker_noise": {"sigma_deg": 0.1, "sigma_mm": 0.5, "sigma_mm_along": 2.0, "source": "estimated"},
        "tracker_noise_dof": {"rot": 56.2, "trans": 33.8, "trans_along": 17.0},
        "cov_x_noise_dof": 66.5,
        "cov_x_dof_factor": 1.0666,
        "tracker_scale": {"value": 2.00022, "sigma": 0.0019},
    }
    items = {it["name"]: it["value"] for it in _tracker(ref)["items"]}
    noise = _noise(ref, tracked=True)["tracker"]
    assert [r["value"] for r in noise["rows"]] == [0.1, 0.5, 2.0] and noise["source"] == "estimated from the views"
    assert "trans along 17" in items["degrees of freedom"] and "1.067" in items["degrees of freedom"]
    assert "F(6, 66)" in items["degrees of freedom"] and "Satterthwaite's 66" in items["degrees of freedom"]
    assert items["translation scale"].startswith("2.00022 ± 0.0019")
    resampled = _tracker(ref | {"cov_x_dof_method": "resampled", "cov_x_dof_factor": 1.171, "cov_x_noise_dof": 21.4})
    line = {it["name"]: it["value"] for it in resampled["items"]}["degrees of freedom"]
    assert "1.171" in line and "repeated on noise drawn" in line and "F(6, 21)" in line and "Satterthwaite" not in line
    stated = {"tracker_noise": {"sigma_deg": 0.1, "sigma_mm": 0.5, "sigma_mm_along": 0.5, "source": "stated"}}
    assert _tracker(stated | {"tracker_noise_dof": {}, "cov_x_noise_dof": None}) is None  # nothing beyond the noise
    assert _tracker({"sigma_px": 0.2}) is None  # an image result has no tracker


def test_the_coverage_warning_speaks_of_given_intrinsics_as_given():
    """With the intrinsics given fixed, a low image coverage does not leave the lens distortion 'only known where
    the board was' (nothing estimated it): the warning says what it does mean."""
    from handeye.report.qa import evaluate

    cfg = {"checks": {"image_coverage": {"warn_below": 0.45}}}
    own = evaluate({"image_coverage": 0.27}, cfg, context={}).checks[0].why
    given = evaluate({"image_coverage": 0.27}, cfg, context={"intrinsics_fixed": True}).checks[0].why
    assert "lens distortion is then only known where the target was" in own
    assert "given intrinsics are then checked against the image only where the target was" in given
    assert "distortion" not in given


def test_the_rotation_axes_ring_labels_sit_where_no_axis_is_drawn():
    """The 30/60/90° labels were drawn at 75° on the disk whatever lay there; they take the ray clear of points."""
    from handeye.report.plots.geometry import _label_angle

    radii = [np.sqrt(1 - np.cos(np.radians(d))) for d in (30, 60, 90)]
    th = np.radians(75.0)
    crowd = np.array([[r * np.cos(th), r * np.sin(th)] for r in radii])  # a point on each ring at 75°
    assert _label_angle(np.zeros((0, 2)), radii) == pytest.approx(th)
    moved = _label_angle(crowd, radii)
    assert abs(np.degrees(moved) - 75.0) >= 15.0
    at = np.array([[r * np.cos(moved), r * np.sin(moved)] for r in radii])
    assert np.min(np.linalg.norm(crowd[:, None] - at[None], axis=2)) >= 0.12
