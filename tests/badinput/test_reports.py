"""Bad input, class "reports": ``handeye report`` on a damaged result folder (exit code 2 naming
result.json and the field), and hostile view ids and folder names, which never run a script in
report.md (rendered with python-markdown, loaded in headless Chromium) or report.html."""

from __future__ import annotations

import html.parser
import json
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


def _set(key, value):
    def f(res):
        res[key] = value

    return f


def damage_file(p: Path, damage) -> None:
    """Apply ``damage`` to result.json: a function of its bytes, or one that changes the parsed dict."""
    try:
        new = damage(p.read_bytes())
    except (TypeError, AttributeError):  # a damage of the parsed dict
        res = json.loads(p.read_text())
        damage(res)
        new = json.dumps(res).encode()
    p.write_bytes(new)


def _matrix(res):
    name = "T_end_cam" if res["mode"] == "eye_in_hand" else "T_base_cam"
    return name


# (damage to result.json: a function of the dict, or the file's new bytes; culprits)
DAMAGE = [
    pytest.param(lambda b: b[: len(b) // 2], ["result.json", "not valid JSON"], id="truncated"),
    pytest.param(lambda b: b"", ["result.json", "not valid JSON"], id="empty"),
    pytest.param(lambda b: b"null", ["result.json", "not a JSON object"], id="null"),
    pytest.param(lambda b: b"[1, 2]", ["result.json", "not a JSON object"], id="a_list"),
    pytest.param(lambda b: b"\xff\xfe" + b, ["result.json", "not valid JSON"], id="not_utf8"),
    pytest.param(lambda b: b"[" * 100000 + b"]" * 100000, ["result.json", "not valid JSON"], id="deep_nesting"),
    pytest.param(_set("status", "maybe"), ["result.json", "status", "'maybe'"], id="status"),
    pytest.param(lambda r: r.pop("status"), ["result.json", "status"], id="no_status"),
    pytest.param(_set("mode", 5), ["result.json", "mode"], id="mode_number"),
    pytest.param(_set("mode", "sideways"), ["result.json", "mode", "sideways"], id="mode_unknown"),
    pytest.param(_set("views", "x"), ["result.json", "views"], id="views_text"),
    pytest.param(_set("views", [1, 2]), ["result.json", "views[0]"], id="views_numbers"),
    pytest.param(_set("views", [{"id": None}]), ["result.json", "views[0]"], id="view_id_null"),
    pytest.param(_set("views", [{"id": "1", "used": "yes"}]), ["result.json", "views[0].used"], id="view_used_text"),
    pytest.param(_set("n_views", "6"), ["result.json", "n_views"], id="n_views_text"),
    pytest.param(
        lambda r: r.update({_matrix(r): [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}), ["result.json", "4x4"], id="matrix_3x3"
    ),
    pytest.param(lambda r: r.update({_matrix(r): [[float("nan")] * 4] * 4}), ["result.json", "4x4"], id="matrix_nan"),
    pytest.param(lambda r: r.pop(_matrix(r)), ["result.json", "4x4"], id="matrix_missing"),
    pytest.param(lambda r: r.pop("hand_eye"), ["result.json", "hand_eye"], id="no_hand_eye"),
    pytest.param(_set("refinement", "x"), ["result.json", "refinement"], id="refinement_text"),
    pytest.param(_set("diagnostics", []), ["result.json", "diagnostics"], id="diagnostics_list"),
    pytest.param(_set("provenance", "x"), ["result.json", "provenance"], id="provenance_text"),
    pytest.param(_set("seconds", [1]), ["result.json", "seconds"], id="seconds_list"),
    pytest.param(_set("findings", {}), ["result.json", "findings"], id="findings_mapping"),
    pytest.param(_set("verdict", 7), ["result.json", "verdict"], id="verdict_number"),
    pytest.param(_set("qa", "x"), ["result.json", "qa"], id="qa_text"),
]


@pytest.mark.parametrize("damage, culprits", DAMAGE)
def test_damaged_result(damage, culprits, good_result, run_cli, names, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    damage_file(out / "result.json", damage)
    rc, err = run_cli("report", out)
    assert rc == 2, err
    names(err, *culprits)


@pytest.mark.parametrize(
    "what, culprits",
    [
        pytest.param("missing", ["no result.json"], id="missing"),
        pytest.param("folder", ["no result.json"], id="result_json_is_a_folder"),
        pytest.param("observations", ["observations.json", "not valid JSON"], id="observations_damaged"),
        pytest.param("nothing", ["no result.json"], id="folder_missing"),
    ],
)
def test_damaged_folder(what, culprits, good_result, run_cli, names, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    if what == "missing":
        (out / "result.json").unlink()
    elif what == "folder":
        (out / "result.json").unlink()
        (out / "result.json").mkdir()
    elif what == "observations":
        (out / "observations.json").write_text("{")
    else:
        out = tmp_path / "nothing"
    rc, err = run_cli("report", out)
    assert rc == 2, err
    names(err, *culprits)


def test_observations_of_another_run_are_ignored(good_result, run_cli, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    obs = json.loads((out / "observations.json").read_text())
    obs["run_id"] = "another"
    (out / "observations.json").write_text(json.dumps(obs))
    from handeye.report.folder import read_result_folder

    assert read_result_folder(out).observations == {}
    assert run_cli("report", out)[0] == 0


@pytest.mark.parametrize("vid", ["<script>alert(1)</script>", "a/b", "../../x", "tab\there", "."])
def test_view_ids_that_are_not_one_name_are_refused(
    vid, tiny_native, copy_session, run_cli, names, fast_failed_load, tmp_path
):
    s = copy_session(tiny_native)
    doc = yaml.safe_load((s / "session.yaml").read_text())
    doc["views"][0]["id"] = vid
    (s / "session.yaml").write_text(yaml.safe_dump(doc))
    rc, err = run_cli("calibrate", s, "--out", tmp_path / "out", "--no-report")
    assert rc == 2
    names(err, "session.yaml", "invalid view id")


PWN = "document.body.setAttribute('data-pwned',{})"
HOSTILE_IDS = [
    f"<img src=x onerror={PWN.format(1)}>",
    f"<svg onload={PWN.format(2)}>",
    f"[click](javascript:{PWN.format(3)})",
    "<iframe src=javascript:alert(4)>",
    f"<b onmouseover={PWN.format(5)}>x",
    f"<details open ontoggle={PWN.format(6)}>",
]
HOSTILE_FOLDER = f"<img src=y onerror={PWN.format(7)}>"


class _Tags(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.bad = []

    def handle_starttag(self, tag, attrs):
        if (
            tag in ("script", "iframe", "svg", "object", "embed")
            or any(k.startswith("on") for k, _ in attrs)
            or any(k in ("href", "src") and (v or "").strip().lower().startswith("javascript:") for k, v in attrs)
        ):
            self.bad.append((tag, attrs))


@pytest.fixture(scope="module")
def hostile_result(tiny_native, tmp_path_factory):
    from handeye.cli import main

    base = tmp_path_factory.mktemp("hostile")
    s = base / HOSTILE_FOLDER
    shutil.copytree(tiny_native, s)
    doc = yaml.safe_load((s / "session.yaml").read_text())
    for v, vid in zip(doc["views"], HOSTILE_IDS, strict=False):
        v["id"] = vid
    (s / "session.yaml").write_text(yaml.safe_dump(doc))
    out = base / "out"
    rc = main(["-q", "calibrate", str(s), "--out", str(out), "--no-refine", "--workers", "1"])
    assert rc in (0, 7)
    res = json.loads((out / "result.json").read_text())
    assert {v["id"] for v in res["views"]} >= set(HOSTILE_IDS[:5])
    return out


def _markdown_html(md_path: Path) -> str:
    import markdown

    body = markdown.markdown(md_path.read_text(encoding="utf-8"), extensions=["tables", "fenced_code"])
    return f"<!doctype html><html><head><meta charset='utf-8'></head><body>{body}</body></html>"


def test_hostile_names_make_no_tags_in_the_markdown(hostile_result):
    parser = _Tags()
    parser.feed(_markdown_html(hostile_result / "report.md"))
    assert not parser.bad, parser.bad
    text = (hostile_result / "report.md").read_text()
    assert "&lt;img src=x onerror" in text  # the id is shown, as text


def test_hostile_names_make_no_tags_in_the_html(hostile_result):
    parser = _Tags()
    parser.feed((hostile_result / "report.html").read_text())
    assert not [b for b in parser.bad if b[0] != "svg"], parser.bad  # the report's own figures may be SVG


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (scripts/test.sh installs it)")
@pytest.mark.parametrize("which", ["md", "html"])
def test_hostile_names_run_no_script_in_chromium(which, hostile_result, tmp_path):
    page = tmp_path / "page.html"
    page.write_text(
        _markdown_html(hostile_result / "report.md") if which == "md" else (hostile_result / "report.html").read_text(),
        encoding="utf-8",
    )
    profile = tmp_path / "profile"
    cmd = [
        CHROMIUM,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--no-first-run",
        "--disable-dev-shm-usage",
        "--disable-background-networking",
        f"--user-data-dir={profile}",
        "--virtual-time-budget=5000",
        "--dump-dom",
        page.as_uri(),
    ]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    assert p.returncode == 0, p.stderr[-1000:]
    assert "<body" in p.stdout and "data-pwned" not in p.stdout.split("<body", 1)[1].split(">", 1)[0]


APPLY = [
    pytest.param(lambda b: b[:40], ["result.json", "not valid JSON"], id="truncated"),
    pytest.param(lambda b: b"[]", ["result.json", "not a JSON object"], id="a_list"),
    pytest.param(_set("status", "failed"), ["failed calibration"], id="failed_result"),
    pytest.param(
        lambda r: r.update({_matrix(r): [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}),
        ["4x4 rigid transform"],
        id="not_rigid",
    ),
    pytest.param(lambda r: r.update({_matrix(r): "identity"}), ["result.json", "4x4"], id="matrix_text"),
    pytest.param(
        lambda r: r.update({_matrix(r): [[1, 0, 0, 0]] * 3 + [[0, 0, "x", 1]]}),
        ["result.json", "4x4"],
        id="matrix_letter",
    ),
]


@pytest.mark.parametrize("damage, culprits", APPLY)
def test_apply_on_a_damaged_result(damage, culprits, good_result, run_cli, names, tmp_path):
    p = tmp_path / "result.json"
    shutil.copy(good_result / "result.json", p)
    damage_file(p, damage)
    rc, err = run_cli("apply", p, "--point", "0", "0", "0.5", "--end-pose", "0.5", "0", "0.4", "0", "0", "0")
    assert rc == 2, err
    names(err, *culprits)


@pytest.mark.parametrize(
    "argv, option",
    [
        pytest.param(["--point", "nan", "0", "0.5"], "--point", id="point_nan"),
        pytest.param(["--point", "1e999", "0", "0.5"], "--point", id="point_overflow"),
        pytest.param(["--pose", "0", "0", "0.5", "0", "0"], "--pose", id="pose_five"),
    ],
)
def test_apply_numbers(argv, option, good_result, run_cli, names):
    rc, err = run_cli("apply", good_result, *argv)
    assert rc == 2, err
    names(err, option)
