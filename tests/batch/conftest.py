"""The batch tests' fixtures: a hook that makes a batch's session process kill its Dask worker."""

from __future__ import annotations

from pathlib import Path

import pytest


def _worker_killing_hook(folder: Path, condition: str) -> Path:
    """``folder/sitecustomize.py`` (``folder`` made), put first on a batch's PYTHONPATH: every session process whose
    ``spec`` meets ``condition`` (a Python expression over ``spec``, the session's job, and ``os``) kills its parent,
    the Dask worker, before it runs. Returns ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "sitecustomize.py").write_text(
        "import sys\n"
        "if 'handeye.batch.child' in sys.orig_argv:\n"
        "    import os, signal, time\n"
        "    import handeye.batch.child as c\n"
        "    _run = c.run\n"
        "    def run(spec):\n"
        f"        if {condition}:\n"
        "            os.kill(os.getppid(), signal.SIGKILL)\n"
        "            time.sleep(30)\n"
        "        return _run(spec)\n"
        "    c.run = run\n"
    )
    return folder


@pytest.fixture
def worker_killing_hook():
    """:func:`_worker_killing_hook`: ``worker_killing_hook(folder, condition)`` writes the hook, returns ``folder``."""
    return _worker_killing_hook
