"""A batch's sessions uploaded to workers that do not share the client's filesystem (``handeye batch --upload``).

The client reads a session's files (:func:`read_tree`) and the site files its options name (:func:`site_files`);
the worker writes them into a temporary folder, calibrates it there and sends the output folder back, which the
client writes under OUT (:func:`write_tree`); the record of the session names the client's paths, not the
worker's (:func:`client_paths`). See docs/fleet.md.
"""

from __future__ import annotations

from pathlib import Path

from ..output import atomic_write_bytes

#: the ``handeye calibrate`` options that name a file, uploaded with each task by ``upload``
SITE_FILE_OPTIONS = ("qa", "config", "prior")


def site_files(calibrate: dict) -> dict:
    """Option -> (file name, bytes) of the files the options name (a result folder: its result.json)."""
    files = {}
    for name in SITE_FILE_OPTIONS:
        if calibrate.get(name):
            p = Path(calibrate[name])
            p = p / "result.json" if p.is_dir() else p
            files[name] = (p.name, p.read_bytes())
    return files


def read_tree(folder: Path) -> dict:
    """Every file under ``folder``: relative POSIX path -> bytes."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(Path(folder).rglob("*")) if p.is_file()}


def write_tree(folder: Path, files: dict, *, keep_prefix: str = "result.") -> None:
    """Write ``files`` (from :func:`read_tree`) under ``folder``.

    Files already there that are not in ``files`` are removed, except those whose name starts with
    ``keep_prefix`` (earlier results the workflow keeps: result.previous.json,
    result.last-good.json).
    """
    folder = Path(folder)
    for rel in files:
        if Path(rel).is_absolute() or ".." in Path(rel).parts:
            raise ValueError(f"unsafe path in an uploaded folder: {rel!r}")
    if folder.is_dir():
        for p in folder.rglob("*"):
            rel = p.relative_to(folder).as_posix()
            if p.is_file() and rel not in files and not p.name.startswith(keep_prefix):
                p.unlink()
    for rel, data in files.items():
        atomic_write_bytes(folder / rel, data, durable=False)


#: the fields of a batch record that may name a file of the session, its output folder or a site file
PATH_FIELDS = ("session", "reason", "export_error", "exported")


def put_back_paths(text: str, paths: dict) -> str:
    """``text`` with every path of ``paths`` (the worker's) written as its value (the client's)."""
    for worker_path in sorted(paths, key=len, reverse=True):  # a longer path before one it starts with
        text = text.replace(worker_path, paths[worker_path])
    return text


def client_paths(rec: dict, paths: dict) -> dict:
    """``rec`` with the paths ``paths`` names (the worker's -> the client's) replaced in :data:`PATH_FIELDS`.

    An uploaded session is calibrated in a temporary folder of the worker, gone by the time anyone reads the
    record: its reasons name the session, the output folder and the site files as the client gave them.
    """

    def put_back(text):
        return put_back_paths(text, paths) if isinstance(text, str) else text

    return {
        k: ([put_back(t) for t in v] if isinstance(v, list) else put_back(v)) if k in PATH_FIELDS else v
        for k, v in rec.items()
    }
