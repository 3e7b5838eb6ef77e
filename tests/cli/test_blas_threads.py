"""handeye.cli: a fresh ``handeye`` process does its linear algebra on one BLAS thread unless the user says."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from handeye.cli import BLAS_THREAD_VARIABLES

CODE = """
import os, sys
{before}
from handeye.cli import _one_blas_thread
_one_blas_thread()
import numpy
numpy.ones((64, 64)) @ numpy.ones((64, 64))  # OpenBLAS has started whatever threads it uses
tasks = len(os.listdir("/proc/self/task")) if os.path.isdir("/proc/self/task") else -1
print(os.environ.get("OPENBLAS_NUM_THREADS"), tasks)
"""


def _run(before: str = "", **env: str) -> tuple[str, int]:
    clean = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    out = subprocess.run(
        [sys.executable, "-c", CODE.format(before=before)], env={**clean, **env}, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stderr
    value, tasks = out.stdout.split()
    return value, int(tasks)


def test_a_fresh_process_uses_one_blas_thread():
    value, tasks = _run()
    assert value == "1"
    if tasks > 0:  # Linux: the process's threads; OpenBLAS would add one per further core
        assert tasks == 1


@pytest.mark.parametrize("var", BLAS_THREAD_VARIABLES)
def test_the_users_setting_is_kept(var):
    value, _ = _run(**{var: "2"})
    assert value == ("2" if var == "OPENBLAS_NUM_THREADS" else "None")


def test_a_process_with_numpy_loaded_is_left_as_it_is():
    value, _ = _run(before="import numpy")
    assert value == "None"
