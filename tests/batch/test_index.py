"""handeye.batch.index: each session is a row on its own (a damaged result.json is a row marked damaged, the
field named), the index is always written, and drift is taken only between comparable sessions.
"""

from __future__ import annotations

import copy
import json
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from handeye.batch import index as index_mod
from handeye.batch.index import DAMAGED, DamagedResult, read_fleet_csv, result_fields, write_index

GOOD = {
    "handeye_result": 1,
    "status": "ok",
    "mode": "eye_in_hand",
    "verdict": "PASS",
    "findings": [{"code": "few_views"}],
    "provenance": {"time_utc": "2026-03-01T00:00:00+00:00"},
    "hand_eye": {"name": "T_end_cam", "translation_mm": [10.0, 20.0, 30.0], "rotvec_deg": [1.0, 2.0, 3.0]},
    "refinement": {"sigma_trans_mm": [0.1, 0.2, 0.3], "sigma_rot_deg": [0.01, 0.02, 0.03], "rms_px_after": 0.25},
}


def _put(d: dict, path: str, value) -> dict:
    d = copy.deepcopy(d)
    *parents, last = path.split(".")
    node = d
    for p in parents:
        node = node[p]
    node[last] = value
    return d


def _session(out: Path, rel: str, *, result=None, text=None, name="result.json", record=None) -> Path:
    folder = out / rel
    folder.mkdir(parents=True)
    if text is None and result is not None:
        text = json.dumps(result)
    if text is not None:
        (folder / name).write_text(text)
    if record is not None:
        (folder / "batch.json").write_text(json.dumps(record))
    return folder


def test_fields_of_a_good_result():
    f = result_fields(GOOD)
    assert f["verdict"] == "PASS" and f["mode"] == "eye_in_hand" and f["findings"] == ["few_views"]
    assert f["translation_mm"] == [10.0, 20.0, 30.0] and f["sigma_rot_deg"] == [0.01, 0.02, 0.03]
    assert f["rms_px"] == 0.25 and f["time_utc"] == "2026-03-01T00:00:00+00:00" and f["sigma_source"] == "model"
    assert result_fields({"handeye_result": 1, "status": "failed"})["verdict"] == "FAIL", "older results: FAIL"


@pytest.mark.parametrize(
    "path, value, field",
    [
        ("verdict", {"PASS": True}, "field verdict is a mapping"),
        ("verdict", "MAYBE", "field verdict is a text"),
        ("mode", ["eye_in_hand"], "field mode is a list"),
        ("findings", {"code": "x"}, "field findings is a mapping"),
        ("provenance", [1], "field provenance is a list"),
        ("provenance.time_utc", 5, "field provenance.time_utc is int"),
        ("hand_eye", "T", "field hand_eye is a text"),
        ("hand_eye.translation_mm", ["a", 0, 0], "field hand_eye.translation_mm[0] is a text"),
        ("hand_eye.rotvec_deg", [1.0, 2.0], "field hand_eye.rotvec_deg is a list"),
        ("refinement.sigma_trans_mm", "abc", "field refinement.sigma_trans_mm is a text"),
        ("refinement.rms_px_after", float("inf"), "field refinement.rms_px_after is float"),  # NaN: no pixels
        ("refinement", [], "field refinement is a list"),
    ],
)
def test_a_field_of_the_wrong_kind_is_named(path, value, field):
    with pytest.raises(DamagedResult) as e:
        result_fields(_put(GOOD, path, value))
    assert str(e.value).startswith(field), str(e.value)
    assert e.value.exit_code == 2 and e.value.code == "result_damaged"


def test_each_damaged_result_is_a_row_and_the_index_is_written(tmp_path):
    out = tmp_path / "out"
    _session(out, "cell-01/good", result=GOOD)
    _session(out, "cell-01/verdict", result=_put(GOOD, "verdict", {"PASS": True}))
    _session(out, "cell-01/cut", text=json.dumps(GOOD)[:40])
    _session(out, "cell-01/list", result=[GOOD])
    _session(out, "cell-01/vector", result=_put(GOOD, "hand_eye.translation_mm", ["a", 0, 0]))
    _session(out, "cell-02/check", text=json.dumps({"verdict": ["drifted"]}), name="verify.json")
    _session(out, "cell-02/rec", result=GOOD, record={"install": {"x": 1}, "name": 7, "outcome": "done"})
    paths = write_index(out, plots=False)
    assert [p.name for p in paths if p.suffix != ".parquet"] == ["fleet.csv", "index.html", "index.md"]
    rows = {r["result_dir"]: r for r in read_fleet_csv(out / "fleet.csv")}
    assert set(rows) == {
        "cell-01/good",
        "cell-01/verdict",
        "cell-01/cut",
        "cell-01/list",
        "cell-01/vector",
        "cell-02/check",
        "cell-02/rec",
    }
    good = rows["cell-01/good"]
    assert good["verdict"] == "PASS" and good["outcome"] == "done" and good["tx_mm"] == 10.0
    damaged = {k: r["reason"] for k, r in rows.items() if r["outcome"] == DAMAGED}
    assert set(damaged) == {"cell-01/verdict", "cell-01/cut", "cell-01/list", "cell-01/vector", "cell-02/check"}
    assert all(rows[k]["verdict"] == "ERROR" and rows[k]["tx_mm"] is None for k in damaged)
    assert damaged["cell-01/verdict"].startswith("result.json is damaged: field verdict is a mapping")
    assert damaged["cell-01/cut"].startswith("result.json is damaged: it is not valid JSON")
    assert damaged["cell-01/list"].startswith("result.json is damaged: field (top level) is a list")
    assert damaged["cell-01/vector"].startswith("result.json is damaged: field hand_eye.translation_mm[0] is a text")
    assert damaged["cell-02/check"].startswith("verify.json is damaged: field verdict is a list")
    rec = rows["cell-02/rec"]  # the record's fields of the wrong kind are passed over: named by the folder
    assert rec["install"] == "cell-02" and rec["session"] == "rec" and rec["verdict"] == "PASS"
    md, html = (out / "index.md").read_text(), (out / "index.html").read_text()
    for text in (md, html):
        assert "Damaged results" in text and "field verdict is a mapping" in text


def test_index_only_over_a_damaged_result_writes_the_index_and_exits_7(tmp_path):
    out = tmp_path / "out"
    _session(out, "cell-01/good", result=GOOD)
    bad = _session(out, "cell-01/bad", result=_put(GOOD, "verdict", {"PASS": True}))

    def index_only():
        return subprocess.run(
            [sys.executable, "-m", "handeye.cli", "batch", "--index-only", str(out)], capture_output=True, text=True
        )

    p = index_only()
    assert p.returncode == 7, p.stderr
    assert "internal error" not in p.stderr and "field verdict is a mapping" in p.stderr
    assert all((out / n).is_file() for n in ("fleet.csv", "index.html", "index.md"))
    assert p.stderr.count("field verdict is a mapping") == 1  # named once, by the index's writer
    (bad / "result.json").write_text(json.dumps(GOOD))
    p = index_only()
    assert p.returncode == 0, p.stderr
    failed = _put(_put(GOOD, "verdict", "FAIL"), "verdict_headline", "T_end_cam fails QA: the board slipped.")
    _session(out, "cell-02/slipped", result=failed)
    p = index_only()
    assert p.returncode == 7 and "cell-02/slipped: FAIL - T_end_cam fails QA: the board slipped." in p.stderr, p.stderr


def test_a_session_whose_result_was_damaged_since_its_run_is_not_skipped(tmp_path):
    from handeye.batch.run import current_record

    key = {"inputs": "folder", "inputs_sha256": "0" * 64, "options": {}}
    rec = {"install": "c", "name": "s", "key": key, "outcome": "done", "verdict": "PASS"}
    folder = _session(tmp_path, "c/s", result=GOOD, record=rec)
    assert current_record(folder, key) == rec
    (folder / "result.json").write_text(json.dumps(_put(GOOD, "verdict", {"PASS": True})))
    assert current_record(folder, key) is None, "calibrated again"


def _loaded(mode="eye_in_hand", board=(11, 8), size=(640, 360)):
    return SimpleNamespace(
        ok=True,
        status="ok",
        mode=mode,
        x_name="T_end_cam" if mode == "eye_in_hand" else "T_base_cam",
        target={"type": "chessboard", "inner_corners": list(board), "square_m": 0.03},
        image_size=size,
        cov_x=object(),
    )


def test_drift_only_within_a_series_and_pairs_across_series_say_why(tmp_path, monkeypatch):
    """An install remounted eye-to-hand for one session and given a 9x6 board and another camera later: each
    session is compared with the previous one of its series; consecutive sessions of two series are listed as
    not comparable with the difference."""
    compared = []
    monkeypatch.setattr(
        index_mod,
        "_drift",
        lambda out, a, b: (
            compared.append((a["session"], b["session"]))
            or {"from": a["session"], "to": b["session"], "comparable": True, "drifted": False, "reason": ""}
        ),
    )
    kinds = {
        "s1": _loaded(),
        "s2": _loaded(mode="eye_to_hand"),
        "s3": _loaded(),
        "s4": _loaded(board=(9, 6)),
        "s5": _loaded(board=(9, 6), size=(1280, 720)),
        "s6": ValueError("result.json: no covariance"),
        "s7": _loaded(),
    }
    rows = [{"session": k, "time_utc": None, "compared": v} for k, v in kinds.items()]
    drifts = index_mod.install_drifts(tmp_path, rows)
    assert compared == [("s1", "s3"), ("s5", "s6"), ("s6", "s7"), ("s3", "s7")]
    why = {(d["from"], d["to"]): d["reason"] for d in drifts if not d["comparable"]}
    assert why == {
        ("s1", "s2"): "mounting modes differ: A is eye_in_hand, B is eye_to_hand",
        ("s2", "s3"): "mounting modes differ: A is eye_to_hand, B is eye_in_hand",
        ("s3", "s4"): (
            "boards differ: A used chessboard 11x8 inner corners, 30 mm, B used chessboard 9x6 inner corners, 30 mm"
        ),
        ("s4", "s5"): "camera resolutions differ: A is 640x360, B is 1280x720",
    }
    assert all(d["drifted"] is False for d in drifts)


def test_a_pose_only_result_is_a_row_of_its_own_not_damaged(tmp_path):
    """A pose-only result has no pixels: its reprojection RMS is NaN, which is not a damaged field; a text
    in that field still is."""
    pose_only = _put(GOOD, "refinement.rms_px_after", float("nan"))
    _session(tmp_path, "c/tracker", result=pose_only)
    _session(tmp_path, "c/edited", result=_put(GOOD, "refinement.rms_px_after", "0.3"))
    write_index(tmp_path, plots=False)
    rows = {r["session"]: r for r in read_fleet_csv(tmp_path / "fleet.csv")}
    assert rows["tracker"]["verdict"] == "PASS" and rows["tracker"]["outcome"] != DAMAGED
    assert rows["tracker"]["reprojection_rms_px"] in ("", None)
    assert rows["edited"]["outcome"] == DAMAGED and "refinement.rms_px_after" in rows["edited"]["reason"]


def test_a_trend_of_sessions_at_one_instant_is_drawn_without_a_warning():
    """Two sessions of an install with the same time (a copied folder, a clock not set): the trend plot has an
    hour each side to draw them in, instead of matplotlib's warning that its date locator found no span."""
    import warnings

    from handeye.batch.index import trend_png

    row = {"time_utc": "2026-03-01T10:00:00+00:00", "tx_mm": 1.0, "ty_mm": 2.0, "tz_mm": 3.0}
    row |= {"rx_deg": 1.0, "ry_deg": 2.0, "rz_deg": 3.0}
    row |= {f"sigma_{a}": 0.1 for a in ("tx_mm", "ty_mm", "tz_mm", "rx_deg", "ry_deg", "rz_deg")}
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        png = trend_png("cell", [row, dict(row, tx_mm=1.5)])
    assert png.startswith(b"\x89PNG")


def test_a_warn_row_says_why_in_the_csv_and_both_indexes(tmp_path):
    """A WARN from a QA check (no finding) had an empty Findings / reason cell: a QA engineer scanning the fleet
    could not tell why. Its row now carries the verdict's headline; a PASS row stays quiet."""
    out = tmp_path / "out"
    headline = "T_end_cam passes with warnings: image area reached by corners 27% < 45%."
    warn = _put(_put(_put(GOOD, "verdict", "WARN"), "findings", []), "verdict_headline", headline)
    _session(out, "cell-01/warn", result=warn)
    _session(out, "cell-01/good", result=GOOD)
    write_index(out, plots=False)
    rows = {r["result_dir"]: r for r in read_fleet_csv(out / "fleet.csv")}
    assert rows["cell-01/warn"]["reason"] == headline and rows["cell-01/good"]["reason"] in ("", None)
    assert "image area reached by corners 27%" in (out / "index.md").read_text()
    assert "image area reached by corners 27% &lt; 45%" in (out / "index.html").read_text()
