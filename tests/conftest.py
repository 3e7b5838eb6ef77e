"""Shared test fixtures. Real datasets live in ../shared/data (never copied into the repo);
tests that need them skip cleanly when that folder is absent."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("HANDEYE_SHARED_DATA", REPO.parent / "shared" / "data"))


def _shared_dataset(name: str) -> Path:
    path = SHARED_DATA / name
    if not path.is_dir():
        pytest.skip(f"real dataset {name} not available ({path} missing)")
    return path


@pytest.fixture(scope="session")
def shared_dataset():
    """``shared_dataset(name)`` -> path of ../shared/data/<name>, or skip the test when absent."""
    return _shared_dataset


@pytest.fixture(autouse=True)
def _no_stray_outputs(monkeypatch, tmp_path):
    # commands that default to ./reports write into the test's own folder
    monkeypatch.chdir(tmp_path)
