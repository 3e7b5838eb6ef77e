"""The benchmarks' fan-out of independent trials: on Dask, as ``handeye batch`` scales out
(:func:`handeye.batch.run.open_client`: an embedded LocalCluster of single-threaded worker processes),
results in the order of the inputs, as they come.

A function of the script being run (``__main__``) is mapped by its module name (``bench_rendered.run_one``),
so the workers import the script as a module (its folder is put on their PYTHONPATH) instead of
receiving a copy of it.
"""

from __future__ import annotations

import importlib
import os
import sys
from pathlib import Path
from typing import Callable, Iterable, Iterator

HERE = Path(__file__).resolve().parent


def _importable(fn: Callable) -> Callable:
    """``fn`` itself, or for a function of the script being run the same function of the script imported
    as a module."""
    if getattr(fn, "__module__", None) != "__main__":
        return fn
    main_file = getattr(sys.modules["__main__"], "__file__", None)
    if main_file is None:
        return fn
    module = importlib.import_module(Path(main_file).stem)
    return getattr(module, fn.__name__)


def ordered_map(fn: Callable, *iterables: Iterable, workers: int) -> Iterator:
    """``map(fn, *iterables)`` on ``workers`` Dask worker processes (in this process when ``workers`` <= 1),
    each result yielded in input order as soon as it and those before it are done."""
    if workers <= 1:
        yield from map(fn, *iterables)
        return
    from handeye.batch.run import open_client

    if str(HERE) not in sys.path:
        sys.path.insert(0, str(HERE))
    paths = os.environ.get("PYTHONPATH", "")
    if str(HERE) not in paths.split(os.pathsep):  # the workers import the benchmark scripts as modules
        os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(HERE), paths) if p)
    task = _importable(fn)
    client = open_client(n_workers=workers)
    try:
        futures = client.map(task, *[list(it) for it in iterables], pure=False)
        for f in futures:
            yield f.result()
    finally:
        client.close()
        client.cluster.close()
