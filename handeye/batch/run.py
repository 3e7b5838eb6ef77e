"""Run a batch of sessions on Dask: one task per session, resumable, isolated.

Each task (:func:`run_session`) hands its session to its worker thread's long-lived session process
(:class:`SessionProcess`: ``python -m handeye.batch.child --serve``, handeye imported once, sessions fed over
a pipe) and waits for the reply with a time limit. A session that hangs (killed at the limit) or crashes
takes only that process with it; the next session starts a fresh one. A child of the worker rather than the
Dask worker itself: a hang is killed without losing the worker, a segfault costs no worker restart. What
happened is recorded in ``OUT/<install>/<session>/batch.json``. A session is skipped when its inputs and
options (:func:`session_key`) match its last finished run. Data reach the workers through a shared
filesystem or uploaded with each task. Nothing here imports the calibration. See docs/fleet.md.
"""

from __future__ import annotations

import itertools
import json
import logging
import os
import socket
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional

from ..contract import BatchRecord, validate_result, write_validated
from ..errors import InputError, QAFailed
from ..output import atomic_write_bytes, command_line, hash_files, write_json, writing
from .discover import SessionJob
from .process import SESSION_ENV, SESSIONS_PER_PROCESS, SessionProcess, _kill_group  # noqa: F401 (re-exported)
from .upload import client_paths, put_back_paths, read_tree, site_files, write_tree

log = logging.getLogger(__name__)

#: the batch's record of a session, beside its result.json
RECORD_NAME = "batch.json"
#: the session child's stderr (its progress and log lines)
LOG_NAME = "batch.log"
#: default time limit of one session (seconds)
DEFAULT_TIMEOUT_S = 900.0
#: the longest time limit of one session (seconds): a week; a longer one is no limit but a mistake
MAX_TIMEOUT_S = 7 * 24 * 3600.0
#: outcomes of a session in the batch: ``done`` (the workflow finished; result.json says the rest),
#: ``timeout``, ``crashed`` (the child died without a result), ``error`` (the workflow raised),
#: ``lost`` (its workers kept dying)
OUTCOMES = ("done", "timeout", "crashed", "error", "lost")
#: tasks submitted per worker thread at once (more are submitted as these finish)
IN_FLIGHT_PER_THREAD = 2
#: the embedded scheduler's ``worker-saturation``: a worker holds only the task it runs, the rest wait on the scheduler
ONE_TASK_PER_THREAD = 1.0
#: times an uploaded session is sent again when its files were lost with their worker (as a task's ``retries``)
UPLOAD_RESENDS = 1
#: verdicts that count as failed in the progress bar and the exit code (ERROR: no result of this run)
FAILED_VERDICTS = ("FAIL", "REFUSED", "ERROR", "DRIFTED")
#: the verdicts of a verification session (handeye verify), as batch records them
VERIFY_VERDICTS = {"still valid": "VALID", "drifted": "DRIFTED"}
#: the verdicts of a calibration whose result ``--export`` writes; a FAIL or REFUSED result (or none) is not
#: exported, by design (handeye export refuses it): that is no failed export
EXPORTED_VERDICTS = ("PASS", "WARN")
#: the verdicts of a calibration that ``--export`` does not write, by design (a verification is never exported)
NOT_EXPORTED_VERDICTS = ("FAIL", "REFUSED", "ERROR")


@dataclass(frozen=True)
class BatchSummary:
    """What a batch did: one record per session (``batch.json``'s content, plus ``skipped``)."""

    records: tuple
    seconds: float
    index_paths: tuple = ()
    export: Optional[str] = None  # the format of ``--export``, when given

    @property
    def counts(self) -> Counter:
        """Done / failed / skipped (failed: verdict FAIL or REFUSED, or no result of this run)."""
        return Counter(record_state(r) for r in self.records)

    @property
    def verdicts(self) -> Counter:
        return Counter(r.get("verdict") or "ERROR" for r in self.records)

    @property
    def export_errors(self) -> list:
        """The records whose export (``calibrate --export``) failed (:func:`export_failed`)."""
        return [r for r in self.records if export_failed(r)]

    @property
    def not_exported(self) -> list:
        """With ``export``: the records of calibrations not exported by design (FAIL, REFUSED, no result)."""
        if not self.export:
            return []
        return [r for r in self.records if (r.get("verdict") or "ERROR") in NOT_EXPORTED_VERDICTS]

    @property
    def exit_code(self) -> int:
        """0 when every session (run or skipped) is PASS or WARN, else :class:`QAFailed`'s code."""
        return QAFailed.exit_code if any(self.verdicts[v] for v in FAILED_VERDICTS) else 0

    def line(self) -> str:
        """The one-line summary."""
        c, v = self.counts, self.verdicts
        verdicts = ", ".join(
            f"{v[k]} {k}" for k in ("PASS", "WARN", "VALID", "FAIL", "REFUSED", "DRIFTED", "ERROR") if v[k]
        )
        exports, unexported = len(self.export_errors), len(self.not_exported)
        return (
            f"{len(self.records)} sessions: {c['done']} done, {c['failed']} failed, {c['skipped']} skipped "
            f"({verdicts or 'none'}) in {self.seconds:.0f} s"
            + (f"; {unexported} not exported (FAIL, REFUSED or no result)" if unexported else "")
            + (f"; the export failed for {exports} session{'s' if exports != 1 else ''}" if exports else "")
        )


def export_failed(rec: dict) -> bool:
    """Whether a session's export (``calibrate --export``) failed: ``export_error`` for a PASS or WARN result.

    A result of another verdict is not exported, by design: an older batch's record of that refusal is no
    failure either.
    """
    return bool(rec.get("export_error")) and rec.get("verdict") in EXPORTED_VERDICTS


def record_state(rec: dict) -> str:
    """Done | failed | skipped for the progress bar."""
    if rec.get("skipped"):
        return "skipped"
    return "failed" if (rec.get("verdict") or "ERROR") in FAILED_VERDICTS else "done"


# ------------------------------------------------------------------------------------------ keys
def _canonical(obj):
    """JSON round trip: tuples become lists, keys strings, as result.json stores them."""
    return json.loads(json.dumps(obj, sort_keys=True, default=str))


def calibrate_namespace(calibrate: dict):
    """The ``handeye calibrate`` arguments of one batch session, with one detection thread.

    The ``handeye calibrate`` arguments of one batch session: ``calibrate`` (its flags by their
    argparse names) with one detection thread (the batch runs sessions side by side).
    """
    import argparse

    return argparse.Namespace(**{**calibrate, "workers": 1})


def provenance_options(calibrate: dict) -> dict:
    """The calibration options as result.json's ``provenance.options`` records them.

    The calibration options as result.json's ``provenance.options`` records them, for the
    command-line options ``calibrate`` (the ``handeye calibrate`` flags by their argparse names).
    """
    from ..options import options_from_args

    o = options_from_args(calibrate_namespace(calibrate))
    return _canonical({"method": o.method, "refine": o.refine, "fix_k3": o.fix_k3, **o.refine_options})


def _file_sha(path) -> Optional[str]:
    """SHA-256 of a file (a result folder: its result.json), None for no path."""
    if path is None:
        return None
    p = Path(path)
    return hash_files([p / "result.json" if p.is_dir() else p])


def inputs_sha256(job: SessionJob, mode: Optional[str], *, allow_outside: bool = False) -> tuple[str, str]:
    """(hash, what it covers) of a session's inputs, as result.json's input hash.

    (hash, what it covers): result.json's input hash (the loaded session's images, poses and
    config), or, for a session that does not load, the hash of every file in its folder.
    """
    from ..errors import HandeyeError
    from ..results import session_inputs
    from ..session import load_session

    try:
        return hash_files(session_inputs(load_session(job.path, mode=mode, allow_outside=allow_outside))), "session"
    except (HandeyeError, ValueError, TypeError, KeyError, OverflowError) as e:
        # a session that does not load (the calibration says why in its own record): keyed on its files
        log.debug("%s: keyed on its files (%s: %s)", job.path, type(e).__name__, e)
        files = sorted(p for p in job.path.rglob("*") if p.is_file())
        return hash_files(files), "folder"


def session_key(job: SessionJob, calibrate: dict, options: dict) -> dict:
    """What a session's outputs depend on (module docstring); ``options`` from :func:`provenance_options`."""
    h, covers = inputs_sha256(job, calibrate.get("mode"), allow_outside=bool(calibrate.get("allow_outside")))
    if job.verify_against:  # a verification: its session and the installed result it is checked against
        against = Path(job.verify_against)
        return _canonical(
            {
                "inputs_sha256": h,
                "inputs": covers,
                "verify_against": str(against),
                "against_sha256": _file_sha(against / "result.json" if against.is_dir() else against),
                "mode": calibrate.get("mode"),
                "report": not calibrate.get("no_report"),
            }
        )
    return _canonical(
        {
            "inputs_sha256": h,
            "inputs": covers,
            "options": options,
            "mode": calibrate.get("mode"),
            "shift_poses": calibrate.get("shift_poses") or 0,
            "report": not calibrate.get("no_report"),
            "qa_sha256": _file_sha(calibrate.get("qa")),
            "config_sha256": _file_sha(calibrate.get("config")),
            "prior_sha256": _file_sha(calibrate.get("prior")),
            "export": calibrate.get("export"),
            **({"board_unmoved": True} if calibrate.get("board_unmoved") else {}),  # keys of earlier runs stay
            "allow_outside": bool(calibrate.get("allow_outside")),
        }
    )


def read_json(path: Path) -> Optional[dict]:
    try:
        d = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def current_record(out_dir: Path, key: dict) -> Optional[dict]:
    """The session's batch record when its last run can be skipped, else None.

    The session's batch record when its last run finished with the same key and its result.json
    still records that key's inputs and options (so the run can be skipped), else None.
    """
    rec = read_json(out_dir / RECORD_NAME)
    if rec is None or rec.get("key") != key or rec.get("outcome") != "done":
        return None
    if key.get("verify_against"):  # the key holds the session's and the installed result's hashes
        return rec if read_json(out_dir / "verify.json") is not None else None
    res = read_json(out_dir / "result.json")
    if res is None:  # missing or not JSON: the session runs again
        return None
    try:  # a result damaged since its run is calibrated again, not carried on as it is
        validate_result(res, source=str(out_dir / "result.json"), partial=True)
    except InputError as e:
        log.warning("%s: the session runs again (%s)", out_dir, e)
        return None
    prov = res.get("provenance") or {}
    if key["inputs"] == "session" and prov.get("inputs_sha256") != key["inputs_sha256"]:
        return None
    if "options" in prov and _canonical(prov["options"]) != key["options"]:
        return None
    return rec


# ------------------------------------------------------------------------------------------ task
def run_session(spec: dict) -> dict:
    """The Dask task of one session.

    Run the workflow in a child process with a time limit, write and return the session's batch
    record. ``spec``: session, out_dir, install, name, time_utc, time_source, key, calibrate (the
    command-line options), timeout_s, and ``files`` (relative path -> bytes) when the client uploads
    the session: it is then written to a temporary folder on the worker, calibrated there, and the
    output folder comes back as ``files`` in the record.
    """
    if spec.get("files") is None:
        return _run_child(spec, Path(spec["out_dir"]))

    with tempfile.TemporaryDirectory(prefix="handeye-batch-") as tmp:
        session, out = Path(tmp) / "session", Path(tmp) / "out"
        write_tree(session, spec["files"])
        # the worker's paths -> the client's, for the record: its reasons name the session the user gave
        paths = {str(session): spec["session"], str(out): spec["out_dir"]}
        calibrate = dict(spec["calibrate"])
        for name, (base, data) in (spec.get("site_files") or {}).items():  # --qa, --config, --prior
            calibrate[name] = str(atomic_write_bytes(Path(tmp) / f"site_{name}" / base, data, durable=False))
            given = Path(spec["calibrate"][name])  # a result folder's result.json was sent: name that file
            paths[calibrate[name]] = str(given if given.name == base else given / base)
        rec = _run_child(
            {
                **spec,
                "files": None,
                "site_files": None,
                "session": str(session),
                "out_dir": str(out),
                "calibrate": calibrate,
                "recorded_paths": paths,  # the result files name the client's paths too
            },
            out,
            paths=paths,
        )
        log = out / LOG_NAME  # and so does the session's log
        if log.is_file():
            log.write_text(put_back_paths(log.read_text(errors="replace"), paths))
        return {**rec, "files": read_tree(out)}


_session_processes = threading.local()  # one per worker thread: a thread runs one session at a time


def session_process() -> SessionProcess:
    """The session process of the calling thread (made on first use, started when it first runs a session)."""
    sp = getattr(_session_processes, "sp", None)
    if sp is None:
        sp = _session_processes.sp = SessionProcess()
    return sp


def _run_child(spec: dict, out: Path, *, paths: Optional[dict] = None) -> dict:
    """Run ``spec`` in this thread's session process and write its record into ``out``.

    ``paths``: the worker's paths -> the client's (an uploaded session), put back in the record's texts.
    """
    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
        (out / LOG_NAME).write_bytes(b"")
    t0 = time.perf_counter()
    rec = spec_record(spec)
    rec.update(worker=f"{socket.gethostname()}:{os.getpid()}", started_utc=_now())
    sp = session_process()
    limit = float(spec["timeout_s"])
    what, reply, code = sp.run({**spec, "log": str(out / LOG_NAME)}, limit)
    if what == "timeout":
        rec.update(
            outcome="timeout",
            verdict="ERROR",
            reason=f"no result within the time limit of {limit:g} s; the session was killed",
        )
    elif what == "died":
        how = "no exit code" if code is None else f"killed by signal {-code}" if code < 0 else f"exit code {code}"
        last = _last_line(out / LOG_NAME)  # with what the process wrote on its own stderr (SessionProcess.run)
        rec.update(
            outcome="crashed", verdict="ERROR", reason=f"the session's process ended without a result ({how}): {last}"
        )
    else:
        rec.update(reply or {})
        if rec.get("verdict") not in EXPORTED_VERDICTS:  # a FAIL result's export is refused by design: no error
            rec.pop("export_error", None)
    return _finish_record(out, client_paths(rec, paths or {}), t0)


def spec_record(spec: dict) -> dict:
    """The start of a session's batch record.

    What the task spec says of the session, and the warnings of its discovery when there were any.
    """
    rec = {k: spec[k] for k in ("session", "install", "name", "time_utc", "time_source", "key")}
    if spec.get("warnings"):
        rec["warnings"] = list(spec["warnings"])
    return rec


def _finish_record(out: Path, rec: dict, t0: float) -> dict:
    rec["seconds"] = time.perf_counter() - t0
    rec["finished_utc"] = _now()
    write_validated(out / RECORD_NAME, rec, BatchRecord)
    return rec


def _last_line(path: Path) -> str:
    try:
        lines = [ln for ln in path.read_text(encoding="utf-8", errors="replace").splitlines() if ln.strip()]
    except OSError:
        return "no log"
    return lines[-1].strip()[:300] if lines else "no log lines"


def _now() -> str:
    import datetime as _dt

    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


# ------------------------------------------------------------------------------------------ batch
@dataclass
class BatchPlan:
    """The sessions to run, to skip, and that cannot run.

    ``specs``: task specs; ``skipped``: current records of unchanged sessions; ``refused``: records of
    sessions that cannot run (outcome ``error``, the reason from discovery or from reading their files).
    """

    specs: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    refused: list = field(default_factory=list)


def plan_batch(
    jobs: list[SessionJob], out: Path, *, calibrate: dict, timeout_s: float = DEFAULT_TIMEOUT_S, force: bool = False
) -> BatchPlan:
    """Decide per session whether it runs (a task spec) or is skipped (its record, ``skipped: true``)."""
    options = provenance_options(calibrate)
    plan = BatchPlan()
    for job in jobs:
        out_dir = Path(out) / job.install / job.name
        spec = {
            "session": str(job.path),
            "out_dir": str(out_dir),
            "install": job.install,
            "name": job.name,
            "time_utc": job.time_utc,
            "time_source": job.time_source,
            "key": None,
            "warnings": list(job.warnings),
        }
        why = job.error
        if why is None:
            try:
                key = session_key(job, calibrate, options)
            except OSError as e:  # the session's files cannot be read: that session fails, the batch goes on
                why = f"its files cannot be read ({e})"
        if why is not None:
            plan.refused.append(_refused_record(spec, why))
            continue
        rec = None if force else current_record(out_dir, key)
        if rec is not None:
            plan.skipped.append({**rec, "skipped": True})
            continue
        plan.specs.append(
            {
                **spec,
                "key": key,
                "calibrate": _canonical(calibrate),
                "command_line": command_line(),  # the batch's, recorded in each result's provenance
                "timeout_s": float(timeout_s),
                "verify_against": job.verify_against,
                "layout": job.layout,  # a cell runs handeye.cell.calibrate_cell
            }
        )
    return plan


def _refused_record(spec: dict, why: str) -> dict:
    """The batch record of a session that cannot run (``why``), written into its output folder."""
    rec = {**spec_record(spec), "outcome": "error", "verdict": "ERROR", "reason": why, "finished_utc": _now()}
    try:
        write_json(Path(spec["out_dir"]) / RECORD_NAME, rec)
    except OSError as w:
        log.warning("%s: could not record that the session cannot run (%s)", spec["out_dir"], w)
    return rec


def open_client(scheduler: Optional[str] = None, n_workers: Optional[int] = None):
    """A Dask client of the cluster at ``scheduler`` or of an embedded LocalCluster.

    A Dask client: of the cluster at ``scheduler`` (``tcp://HOST:8786``), or of an embedded
    LocalCluster of ``n_workers`` single-threaded worker processes (default: the CPU count).
    Close it with ``client.close()`` (and the cluster with ``client.cluster.close()``).
    """
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="30s")
        except OSError as e:  # Dask's "Timed out trying to connect", a refused connection, an unknown host
            raise InputError(
                f"cannot reach the Dask scheduler at {scheduler} ({' '.join(str(e).split())[:120]})",
                hint="check the address and that the scheduler runs there (dask scheduler), or leave out "
                "--scheduler to run on this machine",
            ) from None
    import dask

    n = int(n_workers or os.cpu_count() or 1)
    # one task on a worker at a time (Dask's default, 1.1, gives a single-threaded worker a second one): a worker's
    # death then counts against the session that ran on it alone, never against one queued behind it
    with dask.config.set({"distributed.scheduler.worker-saturation": ONE_TASK_PER_THREAD}):
        cluster = LocalCluster(
            n_workers=n,
            threads_per_worker=1,
            processes=True,
            dashboard_address=":0",  # no fixed port taken
            scheduler_kwargs={"dashboard": False},
        )
    return Client(cluster)


def run_batch(
    jobs: list[SessionJob],
    out,
    *,
    calibrate: dict,
    scheduler: Optional[str] = None,
    n_workers: Optional[int] = None,
    timeout_s: float = DEFAULT_TIMEOUT_S,
    force: bool = False,
    upload: bool = False,
    progress: Optional[Callable[[dict], None]] = None,
) -> BatchSummary:
    """Run ``jobs`` on Dask into ``out`` and return the records of every session (run and skipped).

    ``calibrate``: the ``handeye calibrate`` options by their argparse names (method, no_refine,
    fix_k3, fix, robot_noise, robot_sigma, config, mode, qa, no_report, shift_poses; paths absolute).
    ``upload``: send each session's files to the worker (scattered, see :func:`_run_wave`) and its outputs
    back (workers without the client's filesystem); else the workers read ROOT and write OUT at the
    client's paths. Tasks are
    submitted as workers free up (at most :data:`IN_FLIGHT_PER_THREAD` per worker thread at once),
    so uploaded sessions are read only shortly before they run. ``progress`` gets each session's
    record as it finishes (skipped ones first).
    """
    t0 = time.perf_counter()
    out = Path(out)
    plan = plan_batch(jobs, out, calibrate=calibrate, timeout_s=timeout_s, force=force)
    progress = progress or (lambda rec: None)
    records = []
    for rec in plan.skipped + plan.refused:
        records.append(rec)
        progress(rec)
    if plan.specs:
        client = open_client(scheduler, n_workers)
        try:
            limit = max(2, IN_FLIGHT_PER_THREAD * sum(client.nthreads().values()))
            site = site_files(calibrate) if upload else None
            # a check of a result this batch writes runs after every calibration: its installed result exists then
            later = [s for s in plan.specs if _checks_own_output(s, out)]
            first = [s for s in plan.specs if not _checks_own_output(s, out)]
            for wave in (first, later):
                records += _run_wave(client, wave, limit=limit, upload=upload, site=site, progress=progress)
        finally:
            cluster = None if scheduler else client.cluster
            client.close()
            if cluster is not None:
                cluster.close()
    records.sort(key=lambda r: (r["install"], r.get("time_utc") or "", r["name"]))
    return BatchSummary(tuple(records), time.perf_counter() - t0, export=calibrate.get("export"))


def _checks_own_output(spec: dict, out: Path) -> bool:
    """Whether ``spec`` is a verification of an installed result inside the batch's own output folder."""
    against = spec.get("verify_against")
    if not against:
        return False
    try:
        return Path(against).resolve().is_relative_to(out.resolve())
    except (OSError, ValueError):
        return False


def _run_wave(client, specs: list[dict], *, limit: int, upload: bool, site, progress) -> list[dict]:
    """Run ``specs`` on the cluster, at most ``limit`` in flight, and return their records as they finish.

    ``upload``: each session's files are scattered to a worker (sent to it directly, not through the scheduler
    with the task); a session whose files were lost with their worker before it finished is sent again, up to
    :data:`UPLOAD_RESENDS` times.
    """
    from dask.distributed import as_completed

    records: list[dict] = []
    pending, spec_of, running = iter(specs), {}, as_completed()
    sent: Counter = Counter()

    def submit(spec: dict) -> None:
        files = None
        if upload:
            (files,) = client.scatter([read_tree(Path(spec["session"]))], hash=False)
        task = {**spec, "files": files, "site_files": site} if upload else spec
        fut = client.submit(run_session, task, pure=False, retries=1)
        spec_of[fut.key] = spec, files  # the scattered files are kept until their task is collected
        sent[spec["out_dir"]] += 1
        running.add(fut)

    for spec in itertools.islice(pending, limit):
        submit(spec)
    for fut in running:
        spec, files = spec_of.pop(fut.key)
        if files is not None and fut.cancelled() and sent[spec["out_dir"]] <= UPLOAD_RESENDS:
            fut.release()  # its files were lost with their worker (Dask cancels what needs them): send them again
            submit(spec)
            continue
        rec = _collect(fut, spec)
        outputs = rec.pop("files", None)  # an uploaded session's output folder, sent back
        if outputs is not None:
            write_tree(Path(spec["out_dir"]), outputs)
        fut.release()
        records.append(rec)
        progress(rec)
        nxt = next(pending, None)
        if nxt is not None:
            submit(nxt)
    return records


def _collect(fut, spec: dict) -> dict:
    """A finished future's record; a task that raised or whose workers kept dying is recorded here."""
    if fut.cancelled():  # an uploaded session whose files were lost with their worker again (_run_wave)
        return _lost_record(spec, "the workers holding its uploaded files died")
    try:
        return fut.result()
    except Exception as e:  # noqa: BLE001 - any task failure is one session's, recorded; the batch goes on
        from distributed import KilledWorker

        if isinstance(e, KilledWorker):  # Dask's message (the task's key, the last worker, its advice): in the log
            n = getattr(e, "allowed_failures", None)
            in_a_row = f", {n + 1} in a row" if isinstance(n, int) else ""
            return _lost_record(spec, f"the workers running it died{in_a_row}; Dask's account is in its {LOG_NAME}", e)
        return _lost_record(spec, f"the task failed: {type(e).__name__}: {e}", outcome="error")


def _lost_record(spec: dict, why: str, dask_error=None, *, outcome: str = "lost") -> dict:
    """The record of a session whose task ended without one, into its folder; ``dask_error`` into its log."""
    rec = spec_record(spec)
    rec.update(outcome=outcome, verdict="ERROR", finished_utc=_now(), reason=why)
    try:
        write_json(Path(spec["out_dir"]) / RECORD_NAME, rec)
        if dask_error is not None:
            with open(Path(spec["out_dir"]) / LOG_NAME, "a", encoding="utf-8") as f:
                f.write(f"{rec['finished_utc']} the batch: {why}\n{type(dask_error).__name__}: {dask_error}\n")
    except OSError as w:
        log.warning("%s: could not record the failure (%s)", spec["out_dir"], w)
    return rec
