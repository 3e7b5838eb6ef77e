"""Dependencies point one way: no core module (everything outside handeye.sim and handeye.cli,
the collector included) imports the synthetic-data part."""

from __future__ import annotations

import json
import pkgutil
import subprocess
import sys
import textwrap
from pathlib import Path

import handeye

_OUTSIDE_THE_CORE = ("handeye.sim", "handeye.cli")


def _core_modules() -> list[str]:
    names = ["handeye"]
    for info in pkgutil.walk_packages(handeye.__path__, prefix="handeye."):
        if info.name.endswith("__main__") or info.name.startswith(_OUTSIDE_THE_CORE):
            continue
        names.append(info.name)
    return sorted(names)


def test_the_core_never_imports_the_simulator():
    modules = _core_modules()
    # the packages that must be covered are found (a broken walk would pass vacuously)
    for expected in (
        "handeye.collect.plan",
        "handeye.collect.collector",
        "handeye.collect.visibility",
        "handeye.camera",
        "handeye.frames",
        "handeye.pipeline",
    ):
        assert expected in modules
    script = textwrap.dedent(f"""
        import importlib, json, sys
        for name in {modules!r}:
            importlib.import_module(name)
        print(json.dumps(sorted(m for m in sys.modules if m == "handeye.sim" or m.startswith("handeye.sim."))))
    """)
    proc = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=Path(handeye.__file__).resolve().parents[1],
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == []
