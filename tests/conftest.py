"""Shared test fixtures. Real datasets live in ../shared/data (never copied into the repo).

Tests that need them skip cleanly when that folder is absent, except under CI (``CI=true``), where a
missing dataset is a failure: CI always has ../shared beside the clone, so a skip there would hide
that the real-data tests never ran.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("HANDEYE_SHARED_DATA", REPO.parent / "shared" / "data"))


def in_ci() -> bool:
    return os.environ.get("CI", "").strip().lower() in ("1", "true", "yes")


def require_dataset(name: str) -> Path:
    """Path of ../shared/data/<name>; skip when it is absent, fail when it is absent under CI."""
    path = SHARED_DATA / name
    if not path.is_dir():
        msg = f"real dataset {name} not available ({path} missing)"
        if in_ci():
            pytest.fail(msg + "; CI must run the real-data tests", pytrace=False)
        pytest.skip(msg)
    return path


@pytest.fixture(scope="session")
def shared_dataset():
    """``shared_dataset(name)`` -> path of ../shared/data/<name>, or skip the test when absent."""
    return require_dataset


@pytest.fixture(autouse=True)
def _no_stray_outputs(monkeypatch, tmp_path):
    # commands that default to ./reports write into the test's own folder
    monkeypatch.chdir(tmp_path)


def _session_with_board(session: Path, dest: Path, *, cols: int, rows: int, square_m: float = 0.03) -> Path:
    """A vendor session at ``dest`` that links ``session``'s images and poses but states another board."""
    import yaml

    dest.mkdir()
    for f in session.iterdir():
        (dest / f.name).symlink_to(f)
    (dest / "config.yaml").unlink()
    (dest / "config.yaml").write_text(yaml.safe_dump({"checkerboard_args": {"XX": cols, "YY": rows, "L": square_m}}))
    return dest


@pytest.fixture(scope="session")
def session_with_board():
    """``session_with_board(session, dest, cols=, rows=)``: the session's views under another stated board."""
    return _session_with_board
