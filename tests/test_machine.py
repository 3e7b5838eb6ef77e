"""handeye.machine: the cores a process may use and the memory it keeps."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from handeye import machine

#: three 3 MB arrays alive at once, then freed, 20 times; prints whether the memory was kept and the page faults.
#: By default glibc hands the freed 9 MB at the top of its heap back (more than twice the largest block freed
#: from a mapping of its own), so every round faults the pages in again.
_FAULTS = """
import resource, sys
import numpy as np
from handeye.machine import keep_freed_memory
kept = keep_freed_memory() if sys.argv[1] == "keep" else False
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(20):
    blocks = [np.ones(3 << 17) for _ in range(3)]
    del blocks
print(kept, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""
#: the pages the 20 rounds touch (3 MB arrays of 4 KB pages, three per round)
_PAGES = 20 * 3 * 768


def _faults(how: str, **env: str) -> tuple[str, int]:
    base = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    out = subprocess.run(
        [sys.executable, "-c", _FAULTS, how], env={**base, **env}, capture_output=True, text=True, check=True
    ).stdout.split()
    return out[0], int(out[1])


def _glibc() -> bool:
    try:
        return (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc")
    except (AttributeError, ValueError):
        return False


@pytest.mark.skipif(not _glibc(), reason="the malloc settings are glibc's")
def test_freed_blocks_are_reused_instead_of_faulted_in_again():
    kept, kept_faults = _faults("keep")
    _, default_faults = _faults("default")
    assert kept == "True"
    assert default_faults > _PAGES / 2  # most rounds fault their pages in again
    assert kept_faults < _PAGES / 10  # the first round only


@pytest.mark.skipif(not _glibc(), reason="the malloc settings are glibc's")
@pytest.mark.parametrize(
    "env", [{"MALLOC_TRIM_THRESHOLD_": "131072"}, {"GLIBC_TUNABLES": "glibc.malloc.mmap_threshold=131072"}]
)
def test_the_users_malloc_settings_are_kept(env):
    kept, faults = _faults("keep", **env)
    assert kept == "False"
    assert faults > _PAGES / 2


#: resident memory (MB) over the start after 90 MB of 3 MB arrays are freed with the memory kept, then after
#: it is handed back
_RELEASE = """
import os
import numpy as np
from handeye.machine import keep_freed_memory, release_freed_memory

def resident_mb():
    return int(open("/proc/self/statm").read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

assert keep_freed_memory()
base = resident_mb()
blocks = [np.ones(3 << 17) for _ in range(30)]
del blocks
kept = resident_mb() - base
released = release_freed_memory()
print(released, kept, resident_mb() - base)
"""


@pytest.mark.skipif(not _glibc() or not os.path.exists("/proc/self/statm"), reason="glibc's malloc_trim, Linux")
def test_the_kept_memory_is_handed_back_between_sessions():
    base = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_") and k != "GLIBC_TUNABLES"}
    released, kept_mb, after_mb = subprocess.run(
        [sys.executable, "-c", _RELEASE], env=base, capture_output=True, text=True, check=True
    ).stdout.split()
    assert released == "True"
    assert float(kept_mb) > 60  # the 3 MB blocks stay resident for the next ones
    assert float(after_mb) < 10  # and are handed back when asked


def _unknown_name(name):
    raise ValueError("unrecognized configuration name")


@pytest.mark.parametrize("confstr", [lambda name: None, _unknown_name])
def test_no_glibc_no_settings(monkeypatch, confstr):
    monkeypatch.setattr(machine.os, "confstr", confstr, raising=False)
    assert machine.keep_freed_memory() is False
    assert machine.release_freed_memory() is False


def test_no_ctypes_no_settings(monkeypatch):
    monkeypatch.setitem(sys.modules, "ctypes", None)  # an interpreter built without it: the import fails
    assert machine.keep_freed_memory() is False


def test_usable_cores_follow_the_affinity():
    if not hasattr(os, "sched_getaffinity"):
        pytest.skip("no CPU affinity on this system")
    assert machine.usable_cores() == len(os.sched_getaffinity(0)) >= 1
