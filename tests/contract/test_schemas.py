"""The published JSON schemas (docs/*.schema.json): generated from the models, never stale, and every file a
real run writes validates against them with the jsonschema library."""

import json
from pathlib import Path

import jsonschema
import pytest

from handeye.contract import SCHEMAS, schema_texts
from handeye.contract.__main__ import main as schema_main

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _schema(file_name: str) -> dict:
    s = json.loads((DOCS / file_name).read_text())
    jsonschema.Draft202012Validator.check_schema(s)
    return s


def _errors(instance: dict, file_name: str) -> list:
    v = jsonschema.Draft202012Validator(_schema(file_name))
    return [f"{'.'.join(map(str, e.absolute_path))}: {e.message[:120]}" for e in v.iter_errors(instance)]


def test_the_published_schemas_are_the_generated_ones():
    """If this fails, run ``python -m handeye.contract`` and commit docs/*.schema.json."""
    texts = schema_texts()
    assert set(texts) == {file_name for _, file_name in SCHEMAS.values()}
    for name, text in texts.items():
        assert (DOCS / name).read_text() == text, f"docs/{name} is stale: run python -m handeye.contract"
    assert schema_main(["--check", str(DOCS)]) == 0


def test_the_check_sees_a_stale_schema(tmp_path, capsys):
    assert schema_main([str(tmp_path)]) == 0 and len(list(tmp_path.glob("*.schema.json"))) == 4
    (tmp_path / "result.schema.json").write_text("{}\n")
    assert schema_main(["--check", str(tmp_path)]) == 1
    assert "result.schema.json: differs from the models" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["images", "pose_only", "failed", "unreadable"])
def test_real_results_validate_against_the_published_schema(name, results):
    folder = results[name]
    for file_name in ("result.json", "result.last-good.json"):
        if (folder / file_name).exists():
            assert _errors(json.loads((folder / file_name).read_text()), "result.schema.json") == []
    if (folder / "observations.json").exists():
        assert _errors(json.loads((folder / "observations.json").read_text()), "observations.schema.json") == []


@pytest.mark.parametrize(
    "change, where",
    [
        (lambda d: d["intrinsics"]["dist"].__setitem__("k1", "abc"), "intrinsics"),
        (lambda d: d["intrinsics"].__setitem__("image_size", ["w", "h"]), "intrinsics"),
        (lambda d: d["refinement"].__setitem__("intrinsics_sigma", [0.5]), "refinement"),
        (lambda d: d.__setitem__("verdict", "maybe"), "verdict"),
        (lambda d: d.__setitem__("status", "done"), "status"),
        (lambda d: d.pop("mode"), ""),
    ],
)
def test_the_schema_refuses_what_the_reader_refuses(change, where, results):
    """The structural part of the checks is in the schema too (rigidity and definiteness only in the reader)."""
    d = json.loads((results["images"] / "result.json").read_text())
    change(d)
    found = _errors(d, "result.schema.json")
    assert len(found) == 1 and found[0].startswith(where + ":"), found


def test_a_real_verification_validates_against_the_published_schema(results, tmp_path):
    from handeye.cli import main

    session = results["images"].parent / "images_s"
    rc = main(["-q", "verify", str(session), "--against", str(results["images"]), "--out", str(tmp_path / "v")])
    assert rc == 0
    d = json.loads((tmp_path / "v" / "verify.json").read_text())
    assert d["verdict"] == "still valid" and _errors(d, "verify.schema.json") == []


def test_a_batch_record_validates_against_the_published_schema():
    rec = {
        "session": "/data/cell1/2026-01-01",
        "install": "cell1",
        "name": "2026-01-01",
        "time_utc": "2026-01-01T00:00:00+00:00",
        "time_source": "session.yaml",
        "key": {"inputs_sha256": "0" * 64},
        "outcome": "done",
        "status": "ok",
        "verdict": "WARN",
        "reason": "",
        "exit_code": 0,
        "seconds": 12.5,
    }
    assert _errors(rec, "batch.schema.json") == []
    assert _errors(dict(rec, outcome="finished"), "batch.schema.json") != []
