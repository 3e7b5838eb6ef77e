#!/usr/bin/env python3
"""Print the number of cases of the bad-input suite (tests/badinput/) per class of input.

A class is one test file (``test_<class>.py``); a case is one collected test (one row of a table,
or one property-based test). Usage: ``python scripts/count_badinput.py``.
"""

from __future__ import annotations

import collections
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CLASSES = {  # file stem -> the class's name in the docs
    "test_pose_text": "pose text",
    "test_images": "images",
    "test_configs": "configs",
    "test_native": "native sessions",
    "test_output": "output folders",
    "test_concurrency_kills": "concurrency and kills",
    "test_importers": "importers",
    "test_reports": "reports",
}


def count() -> dict:
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "--collect-only",
            "-q",
            "-p",
            "no:benchmark",
            "-p",
            "no:xdist",
            str(REPO / "tests" / "badinput"),
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
    )
    if p.returncode != 0:
        sys.exit(f"collecting tests/badinput failed:\n{p.stdout[-2000:]}{p.stderr[-2000:]}")
    counts = collections.Counter()
    for line in p.stdout.splitlines():
        if "::" in line:
            stem = Path(line.split("::", 1)[0]).stem
            counts[CLASSES.get(stem, stem)] += 1
    return counts


def main() -> int:
    counts = count()
    width = max(len(c) for c in counts)
    for name in [*CLASSES.values(), *sorted(set(counts) - set(CLASSES.values()))]:
        if name in counts:
            print(f"{name:<{width}}  {counts[name]:>4}")
    print(f"{'total':<{width}}  {sum(counts.values()):>4}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
