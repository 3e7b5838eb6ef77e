"""The whole workflow (load -> calibrate -> diagnose -> write -> report) on rendered vendor sessions,
through :func:`handeye.workflow.calibrate_session`, the function `handeye calibrate` runs."""

import json
from pathlib import Path

import numpy as np
import pytest

from handeye.config import load_preset
from handeye.errors import ConfigError, InputError, SessionRefused, verdict_exit_code
from handeye.frames import pose_error, tangent_difference
from handeye.mounting import mounting
from handeye.pipeline import CalibrateOptions
from handeye.sim.scenarios import default_intrinsics
from handeye.sim.vendor import write_vendor_session
from handeye.workflow import calibrate_session

SMALL = dict(intrinsics=default_intrinsics(640, 480), supersample=3)
#: chi-square quantile, 6 degrees of freedom, p = 0.999: a reported covariance that is honest lets a
#: single error through with probability 0.999; one 2x too small (d2 x4) fails this session (d2 ~8-15)
CHI2_6_999 = 22.458
STAGES = (
    "load",
    "detect",
    "intrinsics",
    "board_poses",
    "closed_form",
    "refine",
    "calibrate",
    "diagnose",
    "write",
    "verdict",
    "report",
    "total",
)


@pytest.fixture(scope="module", params=["eye_in_hand", "eye_to_hand"])
def rendered(request, tmp_path_factory):
    out = tmp_path_factory.mktemp(request.param) / "session"
    write_vendor_session(out, mode=request.param, n_views=12, seed=11, hidden_views=("6",), image_noise=1.0, **SMALL)
    return request.param, out


def _opts(**kw):
    return CalibrateOptions.from_config(load_preset("calibration"), **kw)


def _run(session, out, *, report=False, **kw):
    return calibrate_session(session, options=_opts(**kw), out_dir=out, report=report)


@pytest.fixture(scope="module")
def refined(rendered, tmp_path_factory):
    """The default workflow with its report: refined, diagnosed, written."""
    mode, session = rendered
    out = tmp_path_factory.mktemp("refined") / "out"
    return mode, session, out, calibrate_session(session, options=_opts(), out_dir=out, report=True)


def test_refined_result_agrees_with_the_truth_within_its_reported_covariance(refined):
    mode, session, out, wr = refined
    truth = json.loads((session / "ground_truth.json").read_text())
    res = json.loads((out / "result.json").read_text())
    assert wr.status == "ok" and wr.exit_code == 0 and res == json.loads(json.dumps(wr.result))
    mount = mounting(mode)
    ref = res["refinement"]
    # the covariance's convention (right tangent): T_true = T_x · Exp(xi)
    xi = tangent_difference(np.asarray(res[mount.x_name]), np.asarray(truth[mount.x_name]))
    d2 = float(xi @ np.linalg.solve(np.asarray(ref["cov_x_6x6"]), xi))
    assert d2 < CHI2_6_999, (d2, xi)
    # and the error is small in absolute terms: rendered corners are good to ~0.05 px here
    r, t = pose_error(np.asarray(res[mount.x_name]), np.asarray(truth[mount.x_name]))
    assert t < 5 * np.linalg.norm(ref["sigma_trans_mm"]) and r < 5 * np.linalg.norm(ref["sigma_rot_deg"]), (r, t)
    fx_sigma = ref["intrinsics_sigma"]["fx"]
    assert abs(res["intrinsics"]["fx"] - truth["intrinsics"]["fx"]) < 5 * fx_sigma  # 5 reported sigmas


def test_hidden_view_is_dropped_with_its_pose_and_every_other_view_is_used(refined):
    _, _, out, wr = refined
    views = {v["id"]: v for v in wr.result["views"]}
    assert not views["6"]["used"] and "not found" in views["6"]["reason"]
    assert sorted(k for k, v in views.items() if v["used"]) == sorted(str(k) for k in range(1, 13) if k != 6)
    # every later pair is still right: each view's corners are explained through its own robot pose
    # (the refined sigma_px is ~0.05 px; 1 px is 20 sigma: a view paired with its neighbour's pose is > 20 px off)
    assert max(v["chain_max_px"] for v in views.values() if v["used"]) < 1.0
    obs = json.loads((out / "observations.json").read_text())
    assert sorted(obs["views"]) == sorted(k for k, v in views.items() if v["used"])
    assert list(obs["failed_views"]) == ["6"] and obs["failed_views"]["6"]["reason"] == views["6"]["reason"]
    assert 0 <= obs["failed_views"]["6"]["exposure"]["p5"] <= obs["failed_views"]["6"]["exposure"]["p95"] <= 255
    assert wr.result["n_views"] == {"total": 12, "used": 11}


def test_result_folder_holds_the_outputs_and_seconds_cover_every_stage(refined):
    mode, session, out, wr = refined
    res = wr.result
    assert set(STAGES) <= set(res["seconds"]), res["seconds"]
    stages = sum(res["seconds"][k] for k in ("load", "calibrate", "diagnose", "write", "report"))
    assert stages <= res["seconds"]["total"] + 1e-6
    assert [p.name for p in wr.report_paths] == ["report.html", "report.md"]
    assert all(p.exists() and p.parent == out for p in wr.report_paths)
    assert len(res["provenance"]["inputs_sha256"]) == 64
    # a thumbnail of every view, the hidden one too (the report shows why it was dropped); 640x480 -> ~240 px
    thumbs = sorted(p.stem for p in (out / "thumbnails").glob("*.jpg"))
    assert thumbs == sorted(str(k) for k in range(1, 13))
    import cv2

    h, w = cv2.imread(str(out / "thumbnails" / "6.jpg"), cv2.IMREAD_GRAYSCALE).shape
    assert w == 240 and h == 180
    assert res["frames"][mounting(mode).x_name].startswith("pose of the camera")
    # the closed forms: all seven ran; on these clean views each agrees with the result to ~0.5 deg
    cf = res["closed_form"]
    assert list(cf) == ["tsai", "park", "horaud", "andreff", "daniilidis", "shah", "li"]
    ok = [m for m, e in cf.items() if e["status"] == "ok"]
    assert len(ok) >= 5, cf
    assert max(cf[m]["diff_to_result_deg"] for m in ok) < 0.5 and max(cf[m]["diff_to_result_mm"] for m in ok) < 5.0


def test_the_verdict_is_the_reports_and_result_json_carries_its_checks_and_findings(refined):
    _, _, out, wr = refined
    from handeye.report import build_report_context

    res = json.loads((out / "result.json").read_text())
    verdict = build_report_context(out, make_plots=False)["verdict"]
    assert res["verdict"] == verdict.label == wr.verdict and res["verdict_headline"] == verdict.headline
    assert wr.exit_code == verdict_exit_code(res["verdict"]) == 0 and res["status"] == "ok"
    checks = {c["key"]: c for c in res["qa"]["checks"]}
    assert [c.key for c in verdict.checks] == list(checks)
    rms = checks["reprojection_rms_px"]
    assert rms["limits"] == {"reprojection_rms_px": {"warn_above": 0.8, "fail_above": 1.5}}  # configs/qa.yaml
    assert rms["status"] == "pass" and rms["value"] < 0.8
    diag = res["diagnostics"]["findings"]
    assert [f["code"] for f in res["findings"]] == [f["code"] for f in diag]
    assert all(set(f) == {"code", "severity", "title", "evidence", "action", "view_ids"} for f in res["findings"])
    assert res["mode_source"] == "stated"


def test_a_refusing_finding_drops_the_matrix_and_is_the_reason(rendered, tmp_path, monkeypatch):
    """The workflow's contract with the diagnostics: a finding with ``refuses: true`` refuses the run."""
    import handeye.diagnose as diagnose

    real = diagnose.diagnose_run

    def with_a_refusal(run, **kw):
        d = real(run, **kw)
        d["findings"].insert(
            0,
            {
                "code": "pairs_shuffled",
                "severity": "fail",
                "title": "Images carry other poses",
                "evidence": "9 of 12 images",
                "action": "re-pair them by view id",
                "view_ids": ["1", "2"],
                "details": {"refuses": True},
            },
        )
        return d

    monkeypatch.setattr(diagnose, "diagnose_run", with_a_refusal)
    mode, session = rendered
    wr = _run(session, tmp_path / "out", refine=False)
    res = json.loads((tmp_path / "out" / "result.json").read_text())
    mount = mounting(mode)
    assert wr.status == "failed" and res["status"] == "failed" and res["verdict"] == "REFUSED"
    assert wr.exit_code == SessionRefused.exit_code and res["error"]["type"] == "SessionRefused"
    assert res["error"]["code"] == "pairs_shuffled" and res["error"]["fix"] == "re-pair them by view id"
    assert "Images carry other poses" in res["failure_reason"] and "9 of 12 images" in res["failure_reason"]
    assert not {mount.x_name, mount.board_name, "closed_form", "seed", "refinement", "hand_eye"} & set(res)
    obs = json.loads((tmp_path / "out" / "observations.json").read_text())
    assert not any("residual_chain_px" in v for v in obs["views"].values())  # nothing predicted from a refused X
    assert res["findings"][0]["code"] == "pairs_shuffled"


def test_a_crash_while_judging_never_passes_and_keeps_the_result(rendered, tmp_path, monkeypatch, caplog):
    import handeye.report as report

    def crash(*a, **kw):
        raise RuntimeError("a bug in the QA metrics")

    monkeypatch.setattr(report, "build_report_context", crash)
    mode, session = rendered
    _run(session, tmp_path / "out", refine=False)
    res = json.loads((tmp_path / "out" / "result.json").read_text())
    assert res["status"] == "ok" and mounting(mode).x_name in res  # the matrix survives
    assert res["verdict"] in ("WARN", "FAIL") and res["qa"]["checks"] == [] and "crashed" in res["qa"]["error"]
    assert "could not be evaluated" in res["verdict_headline"] and "a bug in the QA metrics" in caplog.text


def test_a_bad_qa_file_is_refused_before_any_work(tmp_path):
    bad = tmp_path / "qa.yaml"
    bad.write_text("checks:\n  reprojection_rms_px: {warn_over: 1}\n")
    with pytest.raises(ConfigError, match="warn_over") as e:  # before the session is even looked for
        calibrate_session(tmp_path / "no session", options=_opts(), out_dir=tmp_path / "out", qa=bad)
    assert e.value.exit_code == 2 and not (tmp_path / "out").exists()


def test_clean_session_has_no_crashed_diagnostic_stage_and_no_failure(refined):
    _, _, _, wr = refined
    diag = wr.result["diagnostics"]
    assert diag["stages"] and all(st in ("ok", "skipped") for st in diag["stages"].values()), diag.get("stage_errors")
    fails = [f["code"] for f in diag["findings"] if f["severity"] == "fail"]
    assert not fails, fails


def test_closed_form_alone_is_within_ten_refined_sigmas(rendered, tmp_path):
    mode, session = rendered
    truth = json.loads((session / "ground_truth.json").read_text())
    wr = _run(session, tmp_path / "out", refine=False)
    res = wr.result
    assert wr.status == "ok" and not res["refined"] and "refinement" not in res
    mount = mounting(mode)
    r, t = pose_error(np.asarray(res[mount.x_name]), np.asarray(truth[mount.x_name]))
    # the closed form ignores the noise model; the refined sigmas on this session are ~0.02 deg and
    # ~0.05-0.1 mm per axis, the closed form measured 0.02-0.08 deg and 0.1-0.4 mm: 10 refined sigmas
    assert r < 0.2 and t < 1.0, (r, t)
    rb, tb = pose_error(np.asarray(res[mount.board_name]), np.asarray(truth[mount.board_name]))
    assert rb < 0.1 and tb < 0.5, (rb, tb)


def test_a_mode_the_data_contradict_is_refused_without_a_matrix(rendered, tmp_path):
    mode, session = rendered
    wrong = mounting(mode).other
    wr = calibrate_session(
        session, options=_opts(refine=False), out_dir=tmp_path / "out", report=False, mode=wrong.name
    )
    res = json.loads((tmp_path / "out" / "result.json").read_text())
    assert res["error"]["code"] == "mode_swapped" and res["status"] == "failed"
    assert res["verdict"] == "REFUSED" and wr.exit_code == SessionRefused.exit_code
    assert not {wrong.x_name, wrong.board_name, "closed_form", "seed"} & set(res)  # no matrix at all
    assert res["mode_source"] == "flag"


def test_board_size_mismatch_fails_with_a_structured_error_and_no_matrix(rendered, tmp_path, session_with_board):
    _, session = rendered
    bad = session_with_board(session, tmp_path / "bad", cols=9, rows=6)
    wr = calibrate_session(bad, options=_opts(refine=False), out_dir=tmp_path / "out", report=True)
    res = json.loads((tmp_path / "out" / "result.json").read_text())
    assert wr.status == "failed" and wr.exit_code == 3
    assert res["status"] == "failed" and "T_end_cam" not in res and "T_base_cam" not in res
    err = res["error"]
    assert err["code"] == "target_not_found" and err["exit_code"] == 3 and err["file"] == str(bad)
    assert "found in only 0 of 12 images" in err["what"] and "9x6" in err["fix"]
    assert res["failure_reason"] == err["message"]
    assert (tmp_path / "out" / "report.html").exists()  # a failed run still explains itself
    assert all(not v["used"] for v in res["views"]) and len(res["views"]) == 12


def test_degenerate_motion_is_an_error_naming_the_axis(tmp_path):
    # one rotation axis: only roll about the optical axis, no tilts
    session = write_vendor_session(
        tmp_path / "s", mode="eye_in_hand", n_views=6, seed=2, tilt_deg=(0.0, 0.0), min_axis_spread_deg=0.0, **SMALL
    )
    wr = _run(session, tmp_path / "out", refine=False)
    assert wr.exit_code == 4 and wr.status == "failed"
    assert wr.result["error"]["code"] == "motion_one_axis"
    assert "one axis" in wr.result["failure_reason"] and "add views rotated" in wr.result["failure_reason"]
    m = wr.result["motion"]
    assert m["status"] == "degenerate" and m["axis_spread_deg"] < m["min_axis_spread_deg"] == 5.0


def test_failed_run_keeps_the_last_good_result(rendered, tmp_path):
    _, session = rendered
    out = tmp_path / "out"
    assert _run(session, out, refine=False).status == "ok"
    good = (out / "result.json").read_text()
    strict = dict(refine=False, min_rotation_deg=400.0)
    for _ in range(2):  # a second failure must not push the good result out
        wr = _run(session, out, **strict)
        assert wr.status == "failed" and wr.result["error"]["code"] == "motion_small_rotation"
        assert (out / "result.previous.json").read_text() == good
    assert json.loads((out / "result.json").read_text())["status"] == "failed"


def test_unreadable_session_still_gets_a_result_and_a_report(tmp_path):
    s = tmp_path / "s"
    s.mkdir()
    (s / "poses.txt").write_text("1 2 3\n")  # no config.yaml, no images
    wr = calibrate_session(s, options=_opts(), out_dir=tmp_path / "out", report=True)
    res = json.loads((tmp_path / "out" / "result.json").read_text())
    assert wr.status == "failed" and wr.run is None and wr.exit_code == wr.error.exit_code == res["error"]["exit_code"]
    assert res["error"]["code"] == wr.error.code and res["session"]["format"] == "unreadable"
    assert (tmp_path / "out" / "report.html").exists()


def test_missing_session_folder_raises_and_writes_nothing(tmp_path):
    with pytest.raises(InputError):
        calibrate_session(tmp_path / "nope", options=_opts(), out_dir=tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_fixed_intrinsics_stay_fixed(rendered, tmp_path):
    _, session = rendered
    wr = _run(session, tmp_path / "out", refine_options={"fix": ("p1", "p2", "k3")})
    assert wr.status == "ok"
    ref = wr.result["refinement"]
    assert set(ref["intrinsics_sigma"]) == {"fx", "fy", "cx", "cy", "k1", "k2"}
    start = ref["seed"]["intrinsics"]["dist"]
    assert all(ref["intrinsics"]["dist"][k] == start[k] for k in ("p1", "p2", "k3"))
    assert any(ref["intrinsics"]["dist"][k] != start[k] for k in ("k1", "k2"))  # the others did move


def test_a_report_rendering_that_raises_keeps_the_result(rendered, tmp_path, monkeypatch):
    """result.json is written even when rendering the reports raises (an error or an interrupt)."""
    import handeye.workflow as workflow
    from handeye.errors import HandeyeError

    mode, session = rendered

    def boom(ctx, folder, figure_process=None):
        raise HandeyeError("the report template cannot be read")

    monkeypatch.setattr(workflow, "_render_reports", boom)
    out = tmp_path / "out"
    with pytest.raises(HandeyeError):
        _run(session, out, report=True, refine=False)
    res = json.loads((out / "result.json").read_text())
    assert res["status"] == "ok" and res["mode"] == mode and "total" in res["seconds"]
    assert not (out / "report.html").exists()


def test_detections_made_ahead_are_taken_for_the_same_images_only(rendered, monkeypatch):
    """``run_calibration(detected=...)`` takes the detections :func:`detect_ahead` made instead of detecting again
    (the same run), and detects again when they are of other images."""
    import handeye.pipeline as pipeline
    from handeye.session import load_session

    _mode, session = rendered
    s = load_session(session)
    alone = pipeline.run_calibration(s, _opts(validate=False))
    ahead = pipeline.detect_ahead(s, _opts())
    assert ahead is not None and [vid for vid, _p in ahead.items] == [v.view_id for v in s.views]
    calls = []
    real = pipeline.detect_views
    monkeypatch.setattr(
        pipeline, "detect_views", lambda items, *a, **k: calls.append(len(items)) or real(items, *a, **k)
    )
    run = pipeline.run_calibration(s, _opts(validate=False), detected=ahead)
    assert calls == [] and run.status == "ok" and run.seconds["detect"] >= ahead.seconds
    np.testing.assert_array_equal(run.T_x, alone.T_x)
    np.testing.assert_array_equal(run.refined.cov_x_6x6, alone.refined.cov_x_6x6)
    assert [o.n_corners for o in run.outcomes] == [o.n_corners for o in alone.outcomes]
    other = pipeline.Detected(ahead.items[:-1], ahead.min_corners, ahead.results)  # not this session's images
    run = pipeline.run_calibration(s, _opts(validate=False), detected=other)
    assert calls == [len(s.views)] and run.status == "ok"
    np.testing.assert_array_equal(run.T_x, alone.T_x)


def test_every_image_is_hashed_once_as_it_is_decoded(rendered, tmp_path, monkeypatch):
    """provenance.inputs names every file with its SHA-256; the images' come from detection, not a second read."""
    import hashlib

    import handeye.output as output

    read_again: list = []
    real = output.file_sha256
    monkeypatch.setattr(output, "file_sha256", lambda p: read_again.append(Path(p).name) or real(p))
    _mode, session = rendered
    _run(session, tmp_path / "out")
    inputs = json.loads((tmp_path / "out" / "result.json").read_text())["provenance"]["inputs"]
    images = [e for e in inputs if e["path"].endswith(".jpg")]
    assert len(images) == 12  # the hidden view's image too: it was decoded and searched
    for e in inputs:
        assert e["sha256"] == hashlib.sha256((session / e["path"]).read_bytes()).hexdigest()
    assert read_again and not [n for n in read_again if n.endswith(".jpg")]  # poses.txt, config.yaml only
