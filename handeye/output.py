"""Writing outputs: atomic files and self-describing provenance."""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from . import __version__
from .errors import InputError


_UMASK = os.umask(0)
os.umask(_UMASK)


def atomic_write_bytes(path: str | Path, data: bytes, *, durable: bool = True) -> Path:
    """Write ``data`` to ``path`` so that readers see the old file or the whole new one, never half.

    ``durable`` also flushes the bytes to the disk before the rename (survives a power cut; costs a
    disk sync per file): on for results and sessions, off for derived files such as thumbnails."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp creates 0600; outputs are ordinary files
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def atomic_write_text(path: str | Path, text: str, *, durable: bool = True) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"), durable=durable)


def plain(obj, *, nan_to_none: bool = False):
    """JSON/YAML-friendly copy: numpy arrays and scalars become Python lists and numbers, paths
    strings, mapping keys strings; with ``nan_to_none`` non-finite floats become None (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): plain(v, nan_to_none=nan_to_none) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [plain(v, nan_to_none=nan_to_none) for v in obj]
    if isinstance(obj, np.ndarray):
        return plain(obj.tolist(), nan_to_none=nan_to_none)
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, Path):
        return str(obj)
    if nan_to_none and isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def _json_default(o):
    """json's hook for what it cannot encode: the one converter, :func:`plain`."""
    if isinstance(o, (np.ndarray, np.generic, Path)):
        return plain(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def to_json(obj, *, indent: int | None = 2) -> str:
    """JSON text of ``obj`` (numpy values converted); ``indent=None`` writes one compact line, several
    times faster for large files that only programs read."""
    if indent is None:
        return json.dumps(obj, separators=(",", ":"), default=_json_default, allow_nan=True)
    return json.dumps(obj, indent=indent, default=_json_default, allow_nan=True)


def write_json(path: str | Path, obj, *, indent: int | None = 2, durable: bool = True) -> Path:
    """Write ``obj`` as JSON to ``path`` atomically (see :func:`atomic_write_bytes`)."""
    return atomic_write_text(path, to_json(obj, indent=indent) + "\n", durable=durable)


def read_json(path: str | Path) -> dict:
    path = Path(path)
    if path.is_dir():
        path = path / "result.json"
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError("file not found", path=path,
                         hint="run handeye calibrate first or pass the result folder") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"not valid JSON ({e})", path=path) from None


def hash_files(paths) -> str:
    """SHA-256 over the bytes of the given files (in the given order) and their names."""
    h = hashlib.sha256()
    for p in paths:
        p = Path(p)
        h.update(p.name.encode())
        if p.exists():
            with open(p, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
    return h.hexdigest()


def provenance(*, inputs_sha256: str | None = None, extra: dict | None = None) -> dict:
    d = {
        "handeye_version": __version__,
        "command_line": " ".join([Path(sys.argv[0]).name] + sys.argv[1:]) if sys.argv else "",
        "time_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "python": sys.version.split()[0],
    }
    try:
        import cv2

        d["opencv"] = cv2.__version__
    except ImportError:  # pragma: no cover
        pass
    if inputs_sha256:
        d["inputs_sha256"] = inputs_sha256
    if extra:
        d.update(extra)
    return d
