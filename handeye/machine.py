"""What this process may run on (the cores its CPU affinity allows) and how it keeps the memory it frees."""

from __future__ import annotations

import os
from typing import Any

#: mallopt's parameter numbers (glibc's malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: blocks up to this size come from the heap, not from a mapping of their own (glibc's largest on 64 bits)
MMAP_THRESHOLD_BYTES = 32 << 20
#: free memory at the top of a heap that is kept for the next blocks instead of being handed back
TRIM_THRESHOLD_BYTES = 128 << 20
#: glibc's own malloc settings: a user who set any of them keeps them
MALLOC_VARIABLES = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_", "MALLOC_MMAP_MAX_")


def usable_cores() -> int:
    """The cores this process may run on: its CPU affinity where the system has one, else every core."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def keep_freed_memory() -> bool:
    """Let this process reuse the large blocks it frees instead of handing each back to the system.

    By default glibc's malloc maps a large block (an image, its blurred copy, a Jacobian of a few hundred
    views) on its own and unmaps it when freed, and hands the freed memory at the top of its heap back past a
    threshold; both thresholds start at 128 KB and follow the blocks seen. The next block is then faulted in
    again page by page: at 300 views about 250 000 page faults and 1 s of system time in detection alone.
    With it, blocks up to 32 MB come from the heap, and up to 128 MB of freed memory stays there for the
    next ones; the peak memory is about the same (97 MB against 92 MB for the detection of 300 views).
    Returns whether it was set: only with glibc, and not when the environment has malloc settings of its own
    (``MALLOC_*_`` or ``glibc.malloc`` tunables). Called at the start of a ``handeye`` command and of a
    batch's session process.
    """
    if any(v in os.environ for v in MALLOC_VARIABLES) or "glibc.malloc." in os.environ.get("GLIBC_TUNABLES", ""):
        return False
    libc = _glibc()
    if libc is None:
        return False
    mapped = libc.mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)
    return bool(mapped and libc.mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES))


def release_freed_memory() -> bool:
    """Hand the memory this process freed back to the system now (glibc's ``malloc_trim``); whether it could.

    A batch's session process calls it between two sessions: the memory :func:`keep_freed_memory` kept for one
    session's images is not held while it waits, and the next session's peak memory is its own.
    """
    libc = _glibc()
    if libc is None:
        return False
    libc.malloc_trim(0)
    return True


def _glibc() -> Any:
    """The C library of this process when it is glibc (with ``mallopt`` and ``malloc_trim``), else None."""
    try:
        if not (os.confstr("CS_GNU_LIBC_VERSION") or "").startswith("glibc"):
            return None
        import ctypes

        libc = ctypes.CDLL(None)
        return libc if hasattr(libc, "mallopt") and hasattr(libc, "malloc_trim") else None
    # no confstr (Windows), no such name (musl, macOS), no library, an interpreter without ctypes
    except (AttributeError, ValueError, OSError, ImportError):
        return None
