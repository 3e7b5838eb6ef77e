"""One ``handeye`` command in this process, with the wall and CPU time of every stage written to a JSON file.

What ``python -m handeye.cli ARGS`` does, with the stage functions wrapped (each module's attributes
replaced right after the module is imported, by the command as without the timer; nothing in handeye
changed): the interpreter start-up (from the process's start time), ``import handeye.cli``, ``main``
(the whole command; before the workflow it parses the arguments and imports what the command uses),
then per stage the wall and this process's CPU time (all threads). ``outside`` is the workflow's time
not in a named stage; ``exit`` (measured by the caller) is the interpreter's shut-down. Used by
``bench_vs_opencv.py``; prints nothing of its own.

    python benchmarks/timed_cli.py TIMES.json calibrate SESSION --out DIR [...]
"""

from __future__ import annotations

import time

T_START, C_START = time.time(), time.process_time()  # first thing: the interpreter start-up is before this

import atexit  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import sys  # noqa: E402

#: stage name -> (module, attribute) of the function whose calls are that stage
STAGES = {
    "load": ("handeye.session", "load_session"),
    "detect": ("handeye.pipeline", "detect_views"),
    "intrinsics": ("handeye.pipeline", "calibrate_intrinsics"),
    "board_poses": ("handeye.pipeline", "board_poses"),
    "closed_form": ("handeye.pipeline", "_closed_forms"),
    "refine": ("handeye.pipeline", "refine_stage"),
    "validate": ("handeye.pipeline", "validate_stage"),
    "diagnose": ("handeye.diagnose", "diagnose_run"),
    "thumbnails": ("handeye.workflow", "write_thumbnails"),
    "verdict": ("handeye.workflow", "_judge"),
    "report": ("handeye.workflow", "_render_reports"),
    "write result": ("handeye.workflow", "write_result"),
    "write reports": ("handeye.workflow", "_write_reports"),
}


def _process_start() -> float:
    """The UNIX time this process started (Linux: /proc; elsewhere the first line of this file)."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = float(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return time.time() - uptime + start_ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return T_START


class _StageHook:
    """A meta-path finder that lets ``after(module)`` run right after each of ``names`` is executed.

    The stage modules are imported when the command imports them (as without the timer), not before main().
    """

    def __init__(self, names: set, after):
        self.names, self.after = names, after

    def find_spec(self, name, path=None, target=None):
        if name not in self.names:
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None and spec.loader is not None:
                run = spec.loader.exec_module

                def exec_module(module, _run=run):
                    _run(module)
                    self.after(module)

                spec.loader.exec_module = exec_module
                return spec
        return None


def main(out: str, argv: list[str]) -> int:
    times: dict = {"interpreter": {"wall": T_START - _process_start(), "cpu": C_START}}
    spans: dict = {}

    def mark(name: str, w0: float, c0: float) -> None:
        s = spans.setdefault(name, {"wall": 0.0, "cpu": 0.0})
        s["wall"] += time.perf_counter() - w0
        s["cpu"] += time.process_time() - c0

    w0, c0 = time.perf_counter(), time.process_time()
    import handeye.cli as cli

    mark("import handeye.cli", w0, c0)

    # the named stages, and the whole workflow (a span of its own, not a stage)
    timed_functions = {**STAGES, "workflow": ("handeye.workflow", "calibrate_session")}

    def wrap(module) -> None:
        """Time the module's stage functions (and the workflow) once it has run, before anyone imports them."""
        for span, (mod, attr) in timed_functions.items():
            if mod == module.__name__:
                fn = getattr(module, attr)

                def timed(*a, _fn=fn, _span=span, **kw):
                    t, c = time.perf_counter(), time.process_time()
                    try:
                        return _fn(*a, **kw)
                    finally:
                        mark(_span, t, c)

                setattr(module, attr, timed)

    sys.meta_path.insert(0, _StageHook({mod for mod, _ in timed_functions.values()}, wrap))

    def dump() -> None:
        times["stages"] = spans
        times["cpu_total"] = time.process_time()
        times["exit_time"] = time.time()
        with open(out, "w") as f:
            json.dump(times, f)

    atexit.register(dump)
    w0, c0 = time.perf_counter(), time.process_time()
    try:
        return cli.main(argv)
    finally:
        mark("main", w0, c0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1], sys.argv[2:]))
