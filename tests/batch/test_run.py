"""handeye.batch.run: a session that cannot run is recorded as failed with its reason and the batch goes on."""

from __future__ import annotations

import json

import yaml

from handeye.batch.discover import discover
from handeye.batch.run import RECORD_NAME, plan_batch, run_batch
from handeye.cli import build_parser
from handeye.cli.batch import calibrate_options


def test_a_session_that_cannot_run_is_a_failed_record_and_no_worker_is_started(tmp_path):
    root, out = tmp_path / "root", tmp_path / "out"
    folder = root / "cell" / "2026-03-01"
    folder.mkdir(parents=True)
    views = [{"id": "1", "image": "1.jpg", "pose": [0] * 6, "t_image": 1.0e20}]
    (folder / "session.yaml").write_text(yaml.safe_dump({"handeye_session": 1, "verify_against": 5, "views": views}))
    calibrate = calibrate_options(build_parser().parse_args(["batch", str(root), "--out", str(out)]))
    jobs = discover(root)
    plan = plan_batch(jobs, out, calibrate=calibrate)
    assert plan.specs == [] and plan.skipped == [] and len(plan.refused) == 1
    rec = json.loads((out / "cell" / "2026-03-01" / RECORD_NAME).read_text())
    assert rec["outcome"] == "error" and rec["verdict"] == "ERROR" and "verify_against must be a path" in rec["reason"]
    assert rec["time_utc"] == "2026-03-01T00:00:00+00:00" and "t_image 1e+20 is not a time" in rec["warnings"][0]
    seen = []
    summary = run_batch(jobs, out, calibrate=calibrate, progress=seen.append)  # no task: no cluster is started
    assert [r["name"] for r in seen] == ["2026-03-01"] and summary.exit_code == 7
    assert summary.line().startswith("1 sessions: 0 done, 1 failed, 0 skipped (1 ERROR)")
