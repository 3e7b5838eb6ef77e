"""The bad-input suite: every case runs a ``handeye`` command on one broken input and asserts the exit
code of :data:`handeye.errors.EXIT_CODES` and that the one error line names the culprit (file, line,
view or option). Cases are tables (one row each, ``pytest.param(..., id=...)``); each test file is one
class of input, counted by ``scripts/count_badinput.py``.

Sessions are tiny (6 rendered 400x300 views, made once per test process). A session that cannot be
read still gets a result.json from the diagnostics of the failed load; those diagnostics are tested
elsewhere, so here (``fast_failed_load``) they return at once.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from handeye.cli import main

N_VIEWS = 6


@pytest.fixture(scope="session")
def tiny_vendor(tmp_path_factory) -> Path:
    """A rendered vendor session: 1.jpg..6.jpg (400x300), poses.txt, config.yaml (eye-in-hand)."""
    from handeye.sim.scenarios import default_intrinsics
    from handeye.sim.vendor import write_vendor_session

    out = tmp_path_factory.mktemp("badinput") / "vendor"
    write_vendor_session(
        out,
        mode="eye_in_hand",
        n_views=N_VIEWS,
        seed=3,
        intrinsics=default_intrinsics(400, 300),
        supersample=2,
        workers=1,
    )
    return out


@pytest.fixture(scope="session")
def tiny_native(tiny_vendor, tmp_path_factory) -> Path:
    """The same views as a native session.yaml (poses inline, vendor pose format)."""
    import yaml

    from handeye.session import load_session

    s = load_session(tiny_vendor)
    out = tmp_path_factory.mktemp("badinput") / "native"
    out.mkdir()
    for v in s.views:
        shutil.copy(v.image_path, out / v.image_path.name)
    lines = [ln for ln in (tiny_vendor / "poses.txt").read_text().splitlines() if ln.strip()]
    doc = {
        "handeye_session": 1,
        "mode": "eye_in_hand",
        "target": {
            "type": "chessboard",
            "inner_corners": [s.target.cols, s.target.rows],
            "square_m": s.target.square_m,
        },
        "pose_format": {
            "rotation": "euler",
            "euler_order": "xyz",
            "euler_kind": "extrinsic",
            "angle_unit": "rad",
            "translation_unit": "m",
        },
        "views": [
            {
                "id": v.view_id,
                "image": v.image_path.name,
                "pose": [float(x) for x in lines[int(v.view_id) - 1].split(",")],
            }
            for v in s.views
        ],
    }
    (out / "session.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


@pytest.fixture
def copy_session(tmp_path):
    """``copy_session(src, name="s")``: a private copy of a session folder to break."""

    def make(src: Path, name: str = "s") -> Path:
        dest = tmp_path / name
        shutil.copytree(src, dest)
        return dest

    return make


@pytest.fixture
def fast_failed_load(monkeypatch):
    """The diagnostics of a session that cannot be read return at once (they are tested elsewhere)."""
    import handeye.diagnose

    monkeypatch.setattr(handeye.diagnose, "diagnose_session_error", lambda *a, **k: {"findings": []})


@pytest.fixture
def run_cli(capsys):
    """``run_cli(*argv) -> (exit code, stderr)``; asserts the failure is one line without a traceback."""

    def run(*argv, one_line: bool = True):
        capsys.readouterr()
        try:
            rc = main(["-q", *map(str, argv)])
        except SystemExit as e:  # argparse: usage line + one error line
            rc = e.code
        cap = capsys.readouterr()
        assert "Traceback" not in cap.err and "Traceback" not in cap.out
        err_lines = [
            ln
            for ln in cap.err.splitlines()
            if ln.startswith("handeye") and ": error" in ln or ln.startswith("handeye: ")
        ]
        if rc not in (0, 7) and one_line:
            assert len(err_lines) == 1, cap.err
        return rc, cap.err

    return run


def assert_names(err: str, *culprits: str) -> None:
    """The error line names every culprit (a file, line, view, option or value)."""
    for c in culprits:
        assert c in err, f"{c!r} not named in: {err}"


@pytest.fixture(scope="session")
def names():
    return assert_names


@pytest.fixture(scope="session")
def good_result(tiny_vendor, tmp_path_factory) -> Path:
    """A result folder of tiny_vendor with a usable verdict (PASS or WARN), its reports and
    result.last-good.json. Copy it before changing it."""
    import json

    out = tmp_path_factory.mktemp("badinput") / "good"
    rc = main(["-q", "calibrate", str(tiny_vendor), "--out", str(out), "--no-refine", "--workers", "1"])
    res = json.loads((out / "result.json").read_text())
    assert rc == 0 and res["verdict"] in ("PASS", "WARN"), res.get("verdict_headline")
    assert (out / "result.last-good.json").exists() and (out / "report.md").exists()
    return out
