"""Bad input, class "output folders": --out (calibrate, report) that is a file, lies under a file, is
read-only or not writable, or whose disk fills up; checked before the work starts, exit code 2 naming
the folder. And the folder's history: the last good result survives failed runs, no report describes
another result, two sessions of one folder name never share the default folder."""

from __future__ import annotations

import errno
import json
import os
import subprocess

import pytest


def _file(tmp):
    (tmp / "f").write_text("x")
    return tmp / "f"


def _under_file(tmp):
    return _file(tmp) / "sub" / "out"


def _link_to_file(tmp):
    (tmp / "l").symlink_to(_file(tmp))
    return tmp / "l"


def _fifo(tmp):
    os.mkfifo(tmp / "p")
    return tmp / "p"


# (make the --out path, culprits)
OUT_CASES = [
    pytest.param(_file, ["--out is a file"], id="is_a_file"),
    pytest.param(_under_file, ["--out lies under a file"], id="under_a_file"),
    pytest.param(_link_to_file, ["--out is a file"], id="link_to_a_file"),
    pytest.param(_fifo, ["--out is a file", "not a regular folder"], id="named_pipe"),
    pytest.param(lambda tmp: __import__("pathlib").Path("/dev/null"), ["--out is a file"], id="dev_null"),
    pytest.param(
        lambda tmp: __import__("pathlib").Path("/proc/self/handeye-out"), ["--out cannot be written"], id="proc"
    ),
    pytest.param(
        lambda tmp: __import__("pathlib").Path("/sys/kernel/handeye-out"), ["--out cannot be written"], id="sysfs"
    ),
]


@pytest.mark.parametrize("make, culprits", OUT_CASES)
def test_calibrate_out(make, culprits, tiny_vendor, run_cli, names, tmp_path, monkeypatch):
    import handeye.session

    out = make(tmp_path)
    loaded = []
    monkeypatch.setattr(handeye.session, "load_native_session", lambda *a, **k: loaded.append(1))
    monkeypatch.setattr(handeye.session, "load_vendor_session", lambda *a, **k: loaded.append(1))
    rc, err = run_cli("calibrate", tiny_vendor, "--out", out, "--no-report")
    assert rc == 2, err
    names(err, str(out), *culprits)
    assert not loaded  # refused before the session was read


@pytest.mark.parametrize("make, culprits", OUT_CASES[:4])
def test_report_out(make, culprits, good_result, run_cli, names, tmp_path):
    out = make(tmp_path)
    rc, err = run_cli("report", good_result, "--out", out)
    assert rc == 2, err
    names(err, *culprits)


def _unwritable(folder):
    """Make ``folder`` one this user cannot create files in: (undo, the refusal's text). Not root: no write
    permission; root (who ignores permissions): the immutable attribute (chattr +i), else a read-only bind mount
    of the folder onto itself. Skips only where none of these exists here."""
    if os.geteuid() != 0:
        folder.chmod(0o555)
        return (lambda: folder.chmod(0o755)), "Permission denied"
    if subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode == 0:
        return (lambda: subprocess.run(["chattr", "-i", str(folder)], capture_output=True)), "Operation not permitted"
    if subprocess.run(["mount", "--bind", str(folder), str(folder)], capture_output=True).returncode == 0:
        if subprocess.run(["mount", "-o", "remount,bind,ro", str(folder)], capture_output=True).returncode == 0:
            return (lambda: subprocess.run(["umount", str(folder)], capture_output=True)), "Read-only file system"
        subprocess.run(["umount", str(folder)], capture_output=True)
    pytest.skip("root here has neither chattr nor mount: no folder is unwritable to it")


@pytest.fixture
def read_only_folder(tmp_path):
    """(a folder no file can be created in, the refusal's text): a read-only tmpfs where this user may mount
    one, else a folder made unwritable (:func:`_unwritable`)."""
    ro = tmp_path / "ro"
    ro.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(ro)], capture_output=True).returncode:
        undo, reason = _unwritable(ro)
    else:
        undo, reason = (lambda: subprocess.run(["umount", str(ro)], capture_output=True)), "Read-only file system"
    try:
        yield ro, reason
    finally:
        undo()


def test_read_only_out(read_only_folder, tiny_vendor, run_cli, names):
    ro, reason = read_only_folder
    rc, err = run_cli("calibrate", tiny_vendor, "--out", ro / "out", "--no-report")
    assert rc == 2
    names(err, "--out cannot be written", reason, str(ro / "out"))


def test_read_only_out_folder_itself(read_only_folder, tiny_vendor, run_cli, names):
    ro, reason = read_only_folder
    rc, err = run_cli("calibrate", tiny_vendor, "--out", ro, "--no-report")
    assert rc == 2
    names(err, "--out cannot be written", reason, str(ro))


def test_not_writable_out(tiny_vendor, run_cli, names, tmp_path):
    """A folder this user may not write in (for root too: see :func:`_unwritable`)."""
    (tmp_path / "locked").mkdir()
    undo, reason = _unwritable(tmp_path / "locked")
    try:
        rc, err = run_cli("calibrate", tiny_vendor, "--out", tmp_path / "locked" / "out", "--no-report")
    finally:
        undo()
    assert rc == 2
    names(err, "--out cannot be written", reason, str(tmp_path / "locked" / "out"))
    assert not (tmp_path / "locked" / "out").exists()


@pytest.mark.parametrize("target", ["result.json", "observations.json"])
def test_disk_full_keeps_the_previous_result(target, good_result, tiny_vendor, run_cli, names, tmp_path, monkeypatch):
    import shutil

    import handeye.output
    from handeye.report.folder import read_result_folder

    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    before = {p.name: p.read_bytes() for p in out.glob("*.json")}
    real = handeye.output.os.fsync

    def full(fd):
        if os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).startswith("." + target):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(fd)

    monkeypatch.setattr(handeye.output.os, "fsync", full)
    rc, err = run_cli("calibrate", tiny_vendor, "--out", out, "--no-report", "--no-refine")
    assert rc == 2, err
    names(err, "No space left on device", f"cannot write {out / target}")
    after = {p.name: p.read_bytes() for p in out.glob("*.json")}
    # nothing already written is lost or half-written: the previous result, its last good copy and (when the
    # disk filled on it) the previous observations.json are byte for byte as they were
    for name in ("result.json", "result.last-good.json"):
        assert after[name] == before[name], name
    folder = read_result_folder(out)
    if target == "observations.json":
        assert after["observations.json"] == before["observations.json"]
        assert folder.observations["run_id"] == folder.result["run_id"] and folder.observations["views"]
    else:  # this run's observations.json is whole, and not read beside the previous result
        assert json.loads(after["observations.json"])["run_id"] != folder.result["run_id"] and not folder.observations
    assert set(after) == set(before)
    assert not list(out.rglob(".*.tmp")) and not (out / ".handeye.lock").exists()


@pytest.mark.parametrize("failing", [False, True], ids=["good", "failing"])
def test_a_run_writes_result_json_once_and_judges_and_reports_from_one_context(
    failing, good_result, tiny_vendor, copy_session, run_cli, tmp_path, monkeypatch
):
    """One build of the report context (the verdict and the reports), one load of the QA thresholds,
    one atomic write of result.json, then its reports, which carry its run id and verdict."""
    import shutil

    import handeye.report.context
    import handeye.report.qa

    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    session = tiny_vendor
    if failing:
        session = copy_session(tiny_vendor, "bad")
        (session / "poses.txt").write_text("1,2,3\n")
    calls = {"replace": [], "load_qa": 0, "build_context": 0}
    real_replace, real_load_qa, real_build = os.replace, handeye.report.qa.load_qa, handeye.report.context.build_context

    def replace(src, dst):
        calls["replace"].append(os.path.basename(str(dst)))
        return real_replace(src, dst)

    def load_qa(*a, **k):
        calls["load_qa"] += 1
        return real_load_qa(*a, **k)

    def build_context(*a, **k):
        calls["build_context"] += 1
        return real_build(*a, **k)

    monkeypatch.setattr(os, "replace", replace)
    monkeypatch.setattr(handeye.report.qa, "load_qa", load_qa)
    monkeypatch.setattr(handeye.report.context, "build_context", build_context)
    rc, err = run_cli("calibrate", session, "--out", out, "--no-refine", "--workers", "1")
    assert rc == (2 if failing else 0), err
    written = calls["replace"]
    assert written.count("result.json") == 1 and calls["load_qa"] == 1 and calls["build_context"] == 1, calls
    assert written.count("observations.json") == (0 if failing else 1)
    assert written.index("result.json") < written.index("report.html") < written.index("report.md")
    res = json.loads((out / "result.json").read_text())
    assert res["verdict"] == ("FAIL" if failing else json.loads((out / "result.last-good.json").read_text())["verdict"])
    for name in ("report.html", "report.md"):
        text = (out / name).read_text()
        assert res["run_id"] in text and res["verdict"] in text, name


@pytest.mark.parametrize("refused", ["write", "read"])
def test_a_refusal_of_the_file_system_names_the_file_and_a_fix_of_its_kind(
    refused, good_result, tiny_vendor, run_cli, names, tmp_path, monkeypatch
):
    """A write refused names the output and a write fix (space, a writable folder); a read refused names the
    file read and a read fix (its permissions), never output-folder advice."""
    import shutil

    import handeye.output
    from handeye.cli import os_error_line
    from handeye.output import OutputWriteError

    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    if refused == "write":
        real = handeye.output.os.fsync

        def full(fd):
            if os.path.basename(os.readlink(f"/proc/self/fd/{fd}")).startswith(".result.json."):
                raise OSError(errno.ENOSPC, "No space left on device")
            return real(fd)

        monkeypatch.setattr(handeye.output.os, "fsync", full)
    else:
        real = handeye.output.file_sha256

        def unreadable(path):  # the images are hashed as they are decoded: the config is read for its hash
            if str(path).endswith("config.yaml"):
                raise PermissionError(errno.EACCES, "Permission denied", str(path))
            return real(path)

        monkeypatch.setattr(handeye.output, "file_sha256", unreadable)
    rc, err = run_cli("calibrate", tiny_vendor, "--out", out, "--no-report", "--no-refine")
    assert rc == 2, err
    if refused == "write":
        names(
            err,
            f"cannot write {out / 'result.json'}",
            "No space left on device",
            "free space on its disk",
            "choose another output folder",
        )
        assert "cannot read" not in err
    else:
        names(err, f"cannot read {tiny_vendor}", "config.yaml (Permission denied)", "may read it")
        assert "output folder" not in err and "free space" not in err
    line = os_error_line(OSError(errno.EROFS, "Read-only file system", "/mnt/x"))  # only a write gets this
    assert line.startswith("cannot write /mnt/x (Read-only file system) -> make its folder writable")
    assert os_error_line(OutputWriteError(errno.EACCES, "Permission denied", "/o/r.json")).startswith("cannot write")
    assert os_error_line(FileNotFoundError(errno.ENOENT, "No such file", "/s/1.jpg")).startswith("cannot read /s/1.jpg")


def test_failed_runs_keep_the_last_good_result(
    good_result, tiny_vendor, copy_session, run_cli, fast_failed_load, tmp_path
):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    good = json.loads((out / "result.json").read_text())
    bad = copy_session(tiny_vendor, "bad")
    (bad / "poses.txt").write_text("1,2,3\n")
    for _ in range(3):
        rc, _ = run_cli("calibrate", bad, "--out", out, "--no-report")
        assert rc == 2
    assert json.loads((out / "result.json").read_text())["status"] == "failed"
    last = json.loads((out / "result.last-good.json").read_text())
    assert last["run_id"] == good["run_id"] and last["verdict"] in ("PASS", "WARN")
    assert json.loads((out / "result.previous.json").read_text())["run_id"] == good["run_id"]


def test_a_new_result_removes_the_exports_of_the_one_it_replaces(
    good_result, tiny_vendor, copy_session, run_cli, fast_failed_load, tmp_path
):
    """The exports a folder's result.json was given (``export RESULT``, ``calibrate --export``) stayed beside a new
    result of another rig or a failed run, saying "from .../result.json, verdict WARN": a robot loading them got the
    old transform under the new result's name. They go with the result they describe; other files stay."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    for fmt in ("ros2", "json", "urdf"):
        assert run_cli("export", out, "--to", fmt)[0] == 0
    assert run_cli("export", out, "--to", "yaml", "--out", tmp_path / "robot" / "hand_eye.yaml")[0] == 0
    (out / "hand_eye.calib").write_text("the user's own file\n")
    exported = sorted(p.name for p in out.glob("hand_eye.*"))
    assert exported == [
        "hand_eye.calib",
        "hand_eye.json",
        "hand_eye.launch.py",
        "hand_eye.tf_static.yaml",
        "hand_eye.urdf",
        "hand_eye.urdf.xacro",
    ]
    (out / "report_files").mkdir(exist_ok=True)
    (out / "report_files" / "per_view.png").write_bytes(b"the old result's figure")
    bad = copy_session(tiny_vendor, "bad")
    (bad / "poses.txt").write_text("1,2,3\n")
    assert run_cli("calibrate", bad, "--out", out, "--no-report")[0] == 2
    assert not (out / "report_files").exists() and not (out / "report.html").exists()  # the old result's report
    assert sorted(p.name for p in out.glob("hand_eye.*")) == ["hand_eye.calib"]  # not an export of this folder's
    assert (tmp_path / "robot" / "hand_eye.yaml").exists()  # exported elsewhere: the user's to manage


def test_the_report_of_the_last_good_result_is_of_that_file(
    good_result, tiny_vendor, copy_session, run_cli, fast_failed_load, tmp_path
):
    """``report OUT/result.last-good.json`` rebuilt the report of OUT/result.json, a failed run's, and said nothing.
    It is the named file's report, into another folder: in OUT it would replace result.json's."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    good = json.loads((out / "result.json").read_text())
    bad = copy_session(tiny_vendor, "bad")
    (bad / "poses.txt").write_text("1,2,3\n")
    assert run_cli("calibrate", bad, "--out", out, "--no-report")[0] == 2
    rc, err = run_cli("report", out / "result.last-good.json")
    assert rc == 2 and "would replace the reports of this folder's result.json" in err and "--out DIR" in err, err
    rc, err = run_cli("report", out / "result.last-good.json", "--out", tmp_path / "rep", "--format", "md")
    assert rc == 0, err
    md = (tmp_path / "rep" / "report.md").read_text()
    assert f"## Verdict: **{good['verdict']}**" in md and "FAIL" not in md.split("## ", 2)[1], md[:600]
    assert good["run_id"] in md


def test_no_report_removes_the_report_of_the_previous_result(good_result, tiny_vendor, run_cli, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(good_result, out)
    assert (out / "report.md").exists()
    rc, err = run_cli("calibrate", tiny_vendor, "--out", out, "--no-report", "--no-refine")
    assert rc == 0, err
    assert not (out / "report.md").exists() and not (out / "report.html").exists()
    res, obs = (json.loads((out / n).read_text()) for n in ("result.json", "observations.json"))
    assert res["run_id"] == obs["run_id"] == res["provenance"]["run_id"]


def test_default_out_is_unique_per_session_path(tiny_vendor, run_cli, fast_failed_load, tmp_path, monkeypatch):
    import shutil

    for d in ("a", "b"):
        shutil.copytree(tiny_vendor, tmp_path / d / "session")
        (tmp_path / d / "session" / "poses.txt").write_text("1,2\n")  # fails fast at load
    monkeypatch.chdir(tmp_path)
    for d in ("a", "b"):
        run_cli("calibrate", tmp_path / d / "session", "--no-report")
    outs = sorted(p.name for p in (tmp_path / "reports").iterdir())
    assert len(outs) == 2 and all(o.startswith("session-") for o in outs)
    paths = {json.loads((tmp_path / "reports" / o / "result.json").read_text())["session"]["path"] for o in outs}
    assert paths == {str(tmp_path / "a" / "session"), str(tmp_path / "b" / "session")}


def _existing_session(tmp):
    (tmp / "s").mkdir()
    (tmp / "s" / "session.yaml").write_text("handeye_session: 1\n")
    return tmp / "s"


COLLECT_OUT = [
    pytest.param(lambda tmp: _file(tmp), ["OUT is a file, not a folder"], id="is_a_file"),
    pytest.param(lambda tmp: _under_file(tmp), ["OUT lies under a file"], id="under_a_file"),
    pytest.param(
        lambda tmp: _existing_session(tmp), ["output folder is not empty", "never overwritten"], id="existing_session"
    ),
    pytest.param(
        lambda tmp: __import__("pathlib").Path("/proc/self/handeye-out"), ["OUT cannot be written"], id="proc"
    ),
]


@pytest.mark.parametrize("make, culprits", COLLECT_OUT)
def test_collect_out(make, culprits, run_cli, names, tmp_path):
    out = make(tmp_path)
    rc, err = run_cli(
        "collect",
        out,
        "--mode",
        "eye_in_hand",
        "--camera",
        "sim",
        "--robot",
        "sim",
        "--auto",
        "--views",
        "3",
        "--seed",
        "1",
    )
    assert rc == 2, err
    names(err, str(out), *culprits)


def test_a_refusal_s_headline_is_the_report_s_banner_in_result_json_and_on_the_command_line(
    tiny_vendor, copy_session, run_cli, tmp_path, capsys
):
    """Poses shifted by one line: the printed verdict and result.json said "Images and robot poses are out of step
    by 1: ... pairing image k with pose k-1: board scatter 0.002 deg / 0.01 mm ..., a cost of 0.00 against 75.0",
    the report "Pairs shifted by one line: images and robot poses are out of step by 1: image k belongs to pose
    k-1". One headline in all three (docs/report.md: they always agree)."""

    s = copy_session(tiny_vendor)
    lines = (s / "poses.txt").read_text().splitlines()
    (s / "poses.txt").write_text("\n".join(lines[1:] + lines[:1]) + "\n")
    (s / "config.yaml").write_text((s / "config.yaml").read_text() + "mode: eye_in_hand\n")
    capsys.readouterr()
    from handeye.cli import main

    rc = main(["calibrate", str(s), "--out", str(tmp_path / "o")])
    out = capsys.readouterr().out
    assert rc == 8, out
    res = json.loads((tmp_path / "o" / "result.json").read_text())
    head = res["verdict_headline"]
    assert res["verdict"] == "REFUSED" and head.startswith("Pairs shifted by one line: "), head
    assert head.endswith("; no result is given."), head
    md = (tmp_path / "o" / "report.md").read_text()
    banner = next(line for line in md.splitlines() if line.startswith("> **REFUSED** — "))
    assert banner.startswith("> **REFUSED** — " + head.removesuffix("; no result is given.") + ". Fix: "), banner
    assert f"verdict: REFUSED - {head.rstrip('.')}" in out, out


def test_the_printed_sigmas_give_a_small_sigma_its_digits(good_result):
    """``calibrate`` printed "rotation [deg] 0.002 0.002 0.000" where the report showed 0.0003: a sigma is never
    printed as zero."""
    from handeye.cli.calibrate import format_summary

    res = json.loads((good_result / "result.json").read_text())
    res["refinement"] = {"sigma_trans_mm": [0.002, 0.0024, 0.006], "sigma_rot_deg": [0.002, 0.002, 0.0003]}
    line = next(ln for ln in format_summary(res, good_result / "result.json").splitlines() if "1-sigma:" in ln)
    assert line.startswith("  1-sigma: translation [mm] 0.002 0.002 0.006, rotation [deg] 0.002 0.002 0.00030"), line
