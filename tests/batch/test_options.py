"""handeye batch's options: an unusable one is refused up front (exit code 2, one line naming it), before any
session is planned or a cluster started."""

from __future__ import annotations

import pytest

from handeye.batch import run as batch_run
from handeye.cli import main


@pytest.fixture
def root(tmp_path, monkeypatch):
    """A root with one session (it does not load: it is keyed on its files); starting a cluster fails the test."""

    def no_cluster(*a, **kw):
        raise AssertionError("a cluster was started")

    monkeypatch.setattr(batch_run, "open_client", no_cluster)
    folder = tmp_path / "root" / "cell" / "2026-03-01"
    folder.mkdir(parents=True)
    (folder / "poses.txt").write_text("0,0,0,0,0,0\n")
    return tmp_path / "root"


def _refused(capsys, argv) -> str:
    """The one error line of ``handeye batch ARGV``, which must exit with 2."""
    capsys.readouterr()
    rc = main(["batch", *map(str, argv)])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and err.count("\n") == 0 and err.startswith("handeye: error: "), (rc, err)
    return err


@pytest.mark.parametrize("timeout", ["nan", "inf", "-inf", "1e308", "604801", "0", "-5"])
def test_a_timeout_that_is_not_a_finite_positive_time_up_to_a_week_is_refused(root, tmp_path, capsys, timeout):
    err = _refused(capsys, [root, "--out", tmp_path / "out", f"--timeout={timeout}"])
    assert err == (
        f"handeye: error: --timeout must be a positive number of seconds; expected at most 604800 (a week); "
        f"got {float(timeout)} -> pass the time limit of one session, e.g. --timeout 900"
    )
    assert not (tmp_path / "out" / "cell").exists(), "no session was planned"


def test_an_out_that_is_a_file_is_refused(root, tmp_path, capsys):
    (tmp_path / "out").write_text("not a folder\n")
    err = _refused(capsys, [root, "--out", tmp_path / "out"])
    assert err == (
        f"handeye: error: {tmp_path / 'out'}: --out is a file, not a folder; expected a folder (or a new name); "
        "got a file -> pass another folder with --out"
    )
    assert (tmp_path / "out").read_text() == "not a folder\n"


def test_a_missing_prior_and_the_board_unmoved_without_a_prior_are_refused(root, tmp_path, capsys):
    """As ``handeye calibrate`` refuses them, and as the batch refuses a missing --config or --qa."""
    err = _refused(capsys, [root, "--out", tmp_path / "out", "--prior", tmp_path / "nowhere"])
    assert err == (
        f"handeye: error: {tmp_path / 'nowhere'}: file not found -> run handeye calibrate first or pass the result "
        "folder"
    )
    (tmp_path / "earlier").mkdir()
    (tmp_path / "earlier" / "result.json").write_text('{"handeye_result": 1, "status": "ok", "verdict": "PASS"}')
    err = _refused(capsys, [root, "--out", tmp_path / "out", "--prior", tmp_path / "earlier"])
    assert err == (
        f"handeye: error: {tmp_path / 'earlier' / 'result.json'}: damaged: mode is missing; expected the field (it is "
        "required) -> the file was edited or damaged: restore it or calibrate again"
    )
    err = _refused(capsys, [root, "--out", tmp_path / "out", "--board-unmoved"])
    assert err == (
        "handeye: error: --board-unmoved says the board stayed since the earlier calibration given by --prior; "
        "expected --prior RESULT with it; got no --prior -> add --prior RESULT, or drop --board-unmoved"
    )
    assert not (tmp_path / "out" / "cell").exists(), "no session was planned"


def test_a_missing_config_is_refused_before_the_output_folder_is_made(root, tmp_path, capsys):
    err = _refused(capsys, [root, "--out", tmp_path / "out", "--config", tmp_path / "site.yaml"])
    assert "site.yaml: config file not found" in err and not (tmp_path / "out").exists()


def test_an_unreachable_scheduler_is_named_not_blamed_on_the_file_system(monkeypatch):
    import dask.distributed

    from handeye.errors import InputError

    def refused(address, timeout):
        raise OSError(f"Timed out trying to connect to {address} after 30 s")

    monkeypatch.setattr(dask.distributed, "Client", refused)
    with pytest.raises(InputError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:1") as e:
        batch_run.open_client("tcp://127.0.0.1:1")
    assert "leave out --scheduler" in str(e.value)


def test_a_second_batch_into_the_same_output_folder_is_refused_while_the_first_runs(root, tmp_path, capsys):
    import os

    out = tmp_path / "out"
    out.mkdir()
    (out / ".handeye.lock").write_text(f"{os.getppid()}\n")  # a live process holds it: the first batch
    err = _refused(capsys, [root, "--out", out])
    assert f"is in use by another handeye run (pid {os.getppid()})" in err
