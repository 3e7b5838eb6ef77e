"""Time to write both reports (report.html + report.md) from a result folder of a rendered 20-view
1280x720 session (target: about 1 s on 2 cores), and the start-up of the command line.
Prints figures; asserts nothing.

    python benchmarks/bench_report.py [--result DIR] [--views 20] [--repeat 3] [--ref COMMIT]

Without ``--result`` a session is rendered and calibrated first (``handeye simulate --noise-px 2``
and ``handeye calibrate --no-report``). Each figure is measured in a fresh interpreter:

* ``in the workflow``: ``write_reports`` where ``handeye calibrate`` calls it (the pipeline, the
  diagnostics and OpenCV already imported): wall and CPU time (with worker processes, if any),
  with and without the figures;
* ``handeye report DIR``: the whole command in a new process (interpreter start and every import);
* ``handeye --help`` and ``handeye report --help``: wall time in a new process, and
  ``python -X importtime -m handeye.cli report --help``: the summed import time, the modules
  imported, ``handeye.cli``'s own cumulative import time and which heavy libraries were loaded;
* ``per figure``: CPU time of each figure, drawn a second time (imports and caches warm).

``--ref COMMIT`` measures the code of an earlier commit on the same folder (``git archive`` into a
temporary folder; the old API ``write_reports(run, res, out)`` is used when the new one does not
exist), for a before/after comparison.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

_IN_WORKFLOW = r"""
import json, os, sys, time
import handeye.diagnose, handeye.pipeline, cv2  # what the calibrate command has loaded before its report
from handeye.report import write_reports

def cpu():  # this process and its children (an older report drew in worker processes)
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system

out, plots = sys.argv[1], sys.argv[2] == "1"
t, c = time.perf_counter(), cpu()
try:
    write_reports(out, strict=True, plots=plots)
except TypeError:  # an older report API: write_reports(run, res, out_dir)
    from handeye.output import read_json
    res = read_json(out)
    t, c = time.perf_counter(), cpu()
    write_reports(None, res, out, strict=True, plots=plots)
import pathlib
files = pathlib.Path(out, "report_files")
print(json.dumps({"wall": time.perf_counter() - t, "cpu": cpu() - c,
                  "figures": len(list(files.glob("*.png"))) - len(list(files.glob("view_*.png"))),
                  "code": sys.modules["handeye.report"].__file__}))
"""

_PER_FIGURE = r"""
import json, os, sys, time
os.environ["HANDEYE_FIGURE_PROCESSES"] = "1"  # every figure drawn, and timed, in this process
import handeye.report.plots as P
times = {}
for name in ("residual_histogram", "per_view_bars", "image_coverage", "poses_3d", "rotation_coverage",
             "translation_uncertainty"):
    f = getattr(P, name)
    def timed(*a, _f=f, _n=name, **k):
        c = time.process_time()
        png = _f(*a, **k)
        times[_n] = (time.process_time() - c, len(png))
        return png
    setattr(P, name, timed)
from handeye.report import write_reports
write_reports(sys.argv[1], strict=True)
write_reports(sys.argv[1], strict=True)
print(json.dumps(times))
"""


def _run(code: str, *args, env=None) -> dict:
    # run outside the checkout: ``python -c`` puts the working folder first on sys.path
    p = subprocess.run(
        [sys.executable, "-c", code, *map(str, args)],
        check=True,
        capture_output=True,
        text=True,
        env=env,
        cwd=tempfile.gettempdir(),
    )
    return json.loads(p.stdout.strip().splitlines()[-1])


def _best(label: str, runs: list[dict]) -> None:
    walls = [r["wall"] for r in runs]
    cpus = [r["cpu"] for r in runs]
    print(
        f"  {label:46s} wall {min(walls):5.2f} s, cpu {min(cpus):5.2f} s, {runs[-1]['figures']} figures "
        f"[{Path(runs[-1]['code']).parents[2]}] "
        f"(best of {len(runs)}; wall all: " + ", ".join(f"{w:.2f}" for w in walls) + ")"
    )


HEAVY = ("numpy", "scipy", "cv2", "matplotlib", "jinja2", "yaml", "gtsam")


def _importtime(env=None) -> dict:
    """``python -X importtime -m handeye.cli report --help``: summed self times, module count,
    handeye.cli's cumulative time and the heavy libraries imported."""
    p = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "handeye.cli", "report", "--help"],
        capture_output=True,
        text=True,
        env=env,
        cwd=tempfile.gettempdir(),
        check=True,
    )
    total_us, names, cli_us = 0, [], None
    for line in p.stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        self_us, cum_us, name = (x.strip() for x in line[len("import time:") :].split("|"))
        total_us += int(self_us)
        names.append(name)
        if name == "handeye.cli":
            cli_us = int(cum_us)
    return {
        "total_ms": total_us / 1e3,
        "modules": len(names),
        "cli_ms": (cli_us or 0) / 1e3,
        "heavy": [m for m in HEAVY if m in names],
    }


def _wall(argv: list, env=None, repeat: int = 3) -> list[float]:
    """Wall times of ``python -m handeye.cli ARGV`` in a new process, measured by a parent process."""
    code = (
        "import subprocess, sys, time; t = time.perf_counter(); subprocess.run([sys.executable, '-m', "
        "'handeye.cli'] + sys.argv[1:], check=True, stdout=subprocess.DEVNULL); print(time.perf_counter() - t)"
    )
    out = []
    for _ in range(repeat):
        p = subprocess.run(
            [sys.executable, "-c", code, *map(str, argv)],
            check=True,
            capture_output=True,
            text=True,
            env=env,
            cwd=tempfile.gettempdir(),
        )
        out.append(float(p.stdout.strip()))
    return out


def _print_wall(label: str, walls: list[float]) -> None:
    print(
        f"  {label:46s} wall {min(walls):5.2f} s (best of {len(walls)}; all: "
        + ", ".join(f"{w:.2f}" for w in walls)
        + ")"
    )


def _checkout(ref: str, into: Path) -> dict:
    """``handeye`` of commit ``ref`` importable from ``into`` (configs/ and factors/ as in the install)."""
    into.mkdir(parents=True)
    tar = subprocess.run(
        ["git", "-C", str(REPO), "archive", ref, "handeye", "configs", "factors"], check=True, capture_output=True
    ).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=tar, check=True)
    for name in ("configs", "factors"):
        if (into / name).is_dir():
            (into / name).rename(into / "handeye" / name)
    return dict(os.environ, PYTHONPATH=str(into))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--result", type=Path, help="an existing result folder (default: render and calibrate one)")
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--ref", help="also measure the code of this commit (e.g. 807d4c2)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.result is None:
            sess, out = tmp / "s", tmp / "r"
            subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "handeye.cli",
                    "-q",
                    "simulate",
                    str(sess),
                    "--views",
                    str(args.views),
                    "--noise-px",
                    "2",
                ],
                check=True,
                stdout=subprocess.DEVNULL,
            )
            subprocess.run(
                [sys.executable, "-m", "handeye.cli", "-q", "calibrate", str(sess), "--out", str(out), "--no-report"],
                check=True,
                stdout=subprocess.DEVNULL,
            )
        else:
            out = tmp / "r"
            subprocess.run(["cp", "-r", str(args.result), str(out)], check=True)
        res = json.loads((out / "result.json").read_text())
        n_thumbs = len(list((out / "thumbnails").glob("*.jpg"))) if (out / "thumbnails").is_dir() else 0
        print(
            f"result folder: {len(res.get('views') or [])} views, {n_thumbs} thumbnails; cores: {os.cpu_count()}; "
            f"load average: {os.getloadavg()[0]:.1f}"
        )
        envs = [("this checkout", None)]
        if args.ref:
            envs.append((f"commit {args.ref}", _checkout(args.ref, tmp / "ref")))
        for name, env in envs:
            print(f"{name}:")
            _best("both reports, in the workflow", [_run(_IN_WORKFLOW, out, 1, env=env) for _ in range(args.repeat)])
            _best(
                "both reports without figures, in the workflow",
                [_run(_IN_WORKFLOW, out, 0, env=env) for _ in range(args.repeat)],
            )
            # the command line in a new process: the report command on the same folder for every
            # checkout, and the start-up of --help (the parser alone)
            _print_wall("handeye report DIR (new process, all imports)", _wall(["-q", "report", out], env, args.repeat))
            _print_wall("handeye --help (new process)", _wall(["--help"], env, args.repeat))
            _print_wall("handeye report --help (new process)", _wall(["report", "--help"], env, args.repeat))
            imp = min((_importtime(env) for _ in range(args.repeat)), key=lambda r: r["total_ms"])
            print(
                f"  {'-X importtime -m handeye.cli report --help':46s} {imp['total_ms']:6.1f} ms summed over "
                f"{imp['modules']} modules (best of {args.repeat}), handeye.cli cumulative {imp['cli_ms']:.1f} ms; "
                f"heavy libraries imported: {', '.join(imp['heavy']) or 'none'}"
            )
            if env is None:
                figs = _run(_PER_FIGURE, out)
                print(
                    "  per figure (cpu, warm): "
                    + ", ".join(f"{k} {v[0]:.2f} s / {v[1] // 1024} KB" for k, v in figs.items())
                )
                sizes = {p.name: p.stat().st_size for p in (out / "report.html", out / "report.md")}
                print("  sizes: " + ", ".join(f"{k} {v / 1024:.0f} KB" for k, v in sizes.items()))


if __name__ == "__main__":
    main()
