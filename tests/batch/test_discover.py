"""handeye.batch.discover: a bad value in one session.yaml falls back with a warning, links to folders are
followed once (a loop, a second link to one folder, a link to nothing are listed as skipped with the reason).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

from handeye.batch.discover import discover, discover_fleet


def _native(folder: Path, **top) -> Path:
    folder.mkdir(parents=True)
    doc = {"handeye_session": 1, **top}
    (folder / "session.yaml").write_text(yaml.safe_dump(doc))
    return folder


def _vendor(folder: Path) -> Path:
    folder.mkdir(parents=True)
    (folder / "poses.txt").write_text("0,0,0,0,0,0\n")
    return folder


@pytest.mark.parametrize("stamp", [1.0e20, -1.0e20, "1e20", float("nan"), True])
def test_a_t_image_that_is_not_a_time_falls_back_to_the_folder_date_with_a_warning(tmp_path, stamp):
    views = [{"id": "1", "image": "1.jpg", "pose": [0] * 6, "t_image": stamp}, {"id": "2", "image": "2.jpg"}]
    _native(tmp_path / "cell" / "2026-03-01", views=views)
    (job,) = discover(tmp_path)
    assert job.time_utc == "2026-03-01T00:00:00+00:00" and job.time_source == "folder name"
    assert len(job.warnings) == 1 and job.warnings[0].startswith("t_image ") and "not a time" in job.warnings[0]
    assert job.error is None


def test_a_bad_t_image_beside_good_ones_leaves_the_good_ones_the_time(tmp_path):
    views = [
        {"id": "1", "image": "1.jpg", "t_image": 1.0e20},
        {"id": "2", "image": "2.jpg", "t_image": 1772409600.0},  # 2026-03-02T00:00:00Z
    ]
    _native(tmp_path / "cell" / "s", views=views)
    (job,) = discover(tmp_path)
    assert job.time_utc == "2026-03-02T00:00:00+00:00" and job.time_source == "t_image"
    assert job.warnings and "1e+20" in job.warnings[0]


@pytest.mark.parametrize("value", ["yesterday", 12, {"a": 1}, "2026-13-45"])
def test_a_session_time_that_is_not_a_time_falls_back_with_a_warning(tmp_path, value):
    folder = _native(tmp_path / "cell" / "s")
    (folder / "session.yaml").write_text(yaml.safe_dump({"handeye_session": 1, "time": value}))
    (job,) = discover(tmp_path)
    assert job.time_source == "file time" and job.time_utc is not None
    assert "is not an ISO 8601 time" in job.warnings[0]


@pytest.mark.parametrize("value", ["2026-02-30", "2026-01-01T00:00:00+25:00"])
def test_an_unquoted_time_that_does_not_exist_falls_back_with_a_warning(tmp_path, value):
    """YAML reads these as timestamps Python cannot build (PyYAML raises ValueError): the job keeps the file time
    and says why; the calibration then names the file (session.fields.read_yaml)."""
    folder = _native(tmp_path / "cell" / "s")
    (folder / "session.yaml").write_text(f"handeye_session: 1\ntime: {value}\n")
    (job,) = discover(tmp_path)
    assert job.time_source == "file time" and job.time_utc is not None and job.error is None
    assert "session.yaml not read for the batch" in job.warnings[0]
    from handeye.errors import InputError
    from handeye.session.fields import read_yaml

    with pytest.raises(InputError, match="date or time in this file does not exist") as e:
        read_yaml(folder / "session.yaml")
    assert "session.yaml" in str(e.value)


def test_a_session_that_cannot_run_is_a_job_with_its_error_and_the_others_are_found(tmp_path):
    _native(tmp_path / "cell" / "bad", verify_against=5)
    _native(tmp_path / "cell" / "grouped", install={"x": 1})
    _vendor(tmp_path / "cell" / "good")
    (tmp_path / "cell" / "broken").mkdir()
    (tmp_path / "cell" / "broken" / "session.yaml").write_text("views: [unclosed\n")
    jobs = {j.key: j for j in discover(tmp_path)}
    assert set(jobs) == {"cell/bad", "cell/grouped", "cell/good", "cell/broken"}
    assert "verify_against must be a path" in jobs["cell/bad"].error and "got 5" in jobs["cell/bad"].error
    assert jobs["cell/grouped"].error is None and "is not a name" in jobs["cell/grouped"].warnings[0]
    assert "session.yaml not read" in jobs["cell/broken"].warnings[0] and jobs["cell/broken"].error is None
    assert jobs["cell/good"].warnings == () and jobs["cell/good"].error is None


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symbolic links")
def test_links_are_followed_once_and_every_skipped_one_is_listed_with_its_reason(tmp_path):
    root = tmp_path / "root"
    real = _vendor(root / "cell-a" / "2026-01-01")
    outside = _vendor(tmp_path / "elsewhere" / "2026-02-01")
    (root / "cell-b").mkdir()
    os.symlink(outside, root / "cell-b" / "2026-02-01")  # a session outside the root: followed
    os.symlink(real, root / "cell-b" / "again")  # a second way to a session already found
    os.symlink(root / "cell-a", root / "a-link")  # an install reached twice; sorts before the real one
    os.symlink(root, root / "cell-b" / "loop")  # back to the root
    os.symlink(tmp_path / "nowhere", root / "cell-b" / "dead")
    found = discover_fleet(root)
    assert [j.key for j in found.jobs] == ["cell-a/2026-01-01", "cell-b/2026-02-01"], "each session once"
    assert found.jobs[1].path == outside.resolve()
    reasons = {s.path.relative_to(root).as_posix(): s.reason for s in found.skipped}
    assert set(reasons) == {"a-link", "cell-b/again", "cell-b/loop", "cell-b/dead"}
    assert reasons["a-link"] == f"the same folder as {root / 'cell-a'} (reached twice through a link)"
    assert reasons["cell-b/again"] == f"the same folder as {real} (reached twice through a link)"
    assert reasons["cell-b/loop"] == f"a link loop: it leads back to {root}"
    assert reasons["cell-b/dead"].startswith("a link to nothing")


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symbolic links")
def test_a_loop_below_a_linked_folder_is_found_too(tmp_path):
    root = tmp_path / "root"
    target = tmp_path / "installs" / "cell-z"
    _vendor(target / "s1")
    root.mkdir()
    os.symlink(target, root / "cell-z")
    os.symlink(target, target / "self")  # inside the linked install: leads back to it
    found = discover_fleet(root)
    assert [j.key for j in found.jobs] == ["cell-z/s1"]
    assert [(s.path.name, s.reason.split(":")[0]) for s in found.skipped] == [("self", "a link loop")]


def test_a_hidden_folder_holding_a_session_is_listed_as_skipped_and_others_pass_unsaid(tmp_path):
    _native(tmp_path / "cell" / "s")
    _vendor(tmp_path / "cell" / ".old")
    (tmp_path / "cell" / ".cache").mkdir()
    found = discover_fleet(tmp_path)
    assert [j.path.name for j in found.jobs] == ["s"]
    assert [(s.path.name, s.reason) for s in found.skipped] == [
        (".old", "a hidden folder (its name starts with a dot)")
    ]


def test_a_session_given_as_the_root_dot_keeps_its_folder_date(tmp_path, monkeypatch):
    folder = _native(tmp_path / "2026-01-01")
    monkeypatch.chdir(folder)
    (job,) = discover(Path("."))
    assert job.time_utc == "2026-01-01T00:00:00+00:00" and job.time_source == "folder name"
