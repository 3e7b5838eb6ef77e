"""Writing outputs safely, and the one reader of text input files.

Atomic files, output folders checked before the work, one run at a time per folder (a lock file with
the holder's pid), self-describing provenance; text inputs are read with BOM and common encodings
handled, the others named.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import sys
import tempfile
from contextlib import contextmanager
from contextvars import ContextVar
from pathlib import Path
from typing import Iterator, Mapping, Optional

import numpy as np

from . import __version__
from .errors import InputError, OutputError

_UMASK = os.umask(0)
os.umask(_UMASK)

#: suffix of the temporary files :func:`atomic_write_bytes` renames into place (``.NAME.XXXX.tmp``);
#: a killed run may leave one, the next run in the folder removes it (:func:`remove_stray_temps`)
TEMP_SUFFIX = ".tmp"
#: the lock file of a folder a run is writing into (:class:`FolderLock`)
LOCK_NAME = ".handeye.lock"


class OutputWriteError(OSError):
    """The file system refused to write an output.

    The file system refused to write an output (disk full, read-only, permissions): ``filename`` is
    the output, ``errno`` and ``strerror`` the refusal's; the original OSError is its ``__cause__``. What
    tells a write error from a read error (the command line gives each its own advice).
    """


@contextmanager
def writing(path: str | Path):
    """Context in which an OSError is re-raised as an :class:`OutputWriteError` for ``path``.

    Inside, an OSError is one of writing ``path`` (an output file or folder): re-raised as
    :class:`OutputWriteError` naming the file it names, else ``path``.
    """
    try:
        yield
    except OutputWriteError:
        raise
    except OSError as e:
        raise OutputWriteError(e.errno, e.strerror or str(e), str(e.filename or path)) from e


def atomic_write_bytes(path: str | Path, data: bytes, *, durable: bool = True) -> Path:
    """Write ``data`` to ``path`` so that readers see the old file or the whole new one, never half.

    ``durable`` also flushes the bytes to the disk before the rename (survives a power cut; costs a
    disk sync per file): on for results and sessions, off for derived files such as thumbnails.
    A refusal of the file system is an :class:`OutputWriteError` naming ``path``.
    """
    path = Path(path)
    with writing(path):  # names the folder that cannot be made
        path.parent.mkdir(parents=True, exist_ok=True)
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix="." + path.name + ".", suffix=TEMP_SUFFIX, dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp creates 0600; outputs are ordinary files
        os.replace(tmp, path)
    except BaseException as e:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
        if isinstance(e, OSError) and not isinstance(e, OutputWriteError):
            raise OutputWriteError(e.errno, e.strerror or str(e), str(path)) from e  # the output, not its temp
        raise
    return path


def atomic_write_text(path: str | Path, text: str, *, durable: bool = True) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"), durable=durable)


def plain(obj, *, nan_to_none: bool = False):
    """JSON/YAML-friendly copy: numpy arrays and scalars become Python lists and numbers, paths strings.

    JSON/YAML-friendly copy: numpy arrays and scalars become Python lists and numbers, paths
    strings, mapping keys strings; with ``nan_to_none`` non-finite floats become None (strict JSON).
    """
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
    """Json's hook for what it cannot encode: the one converter, :func:`plain`."""
    if isinstance(o, (np.ndarray, np.generic, Path)):
        return plain(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def to_json(obj, *, indent: int | None = 2) -> str:
    """JSON text of ``obj`` (numpy values converted).

    ``indent=None`` writes one compact line, several times faster for large files that only programs
    read.
    """
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
        raise InputError(
            "file not found", path=path, hint="run handeye calibrate first or pass the result folder"
        ) from None
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


#: how the runs of this context are recorded when that is not this process's own way (:func:`recorded_as`)
_RECORDED_AS: ContextVar[Optional[dict]] = ContextVar("handeye_recorded_as", default=None)


@contextmanager
def recorded_as(*, command_line: Optional[str] = None, paths: Optional[Mapping[str, str]] = None) -> Iterator[None]:
    """Record the runs inside as their user started them.

    ``command_line`` goes into their provenance, and every path inside a key of ``paths`` (a copy made for the
    run) is recorded as the same path inside its value (the path the user gave). A batch's session process runs
    each session as ``handeye calibrate`` does, but its own command line is the process's, and an uploaded
    session is read from a temporary copy on its worker; neither names anything the reader of the result can find.
    """
    token = _RECORDED_AS.set({"command_line": command_line, "paths": dict(paths or {})})
    try:
        yield
    finally:
        _RECORDED_AS.reset(token)


def recorded_path(path: str | Path) -> str:
    """``path`` as the result files record it: inside the path the user gave where it is inside a run's copy."""
    p = Path(path)
    copies = (_RECORDED_AS.get() or {}).get("paths") or {}
    for copy in sorted(copies, key=len, reverse=True):  # a longer path before one it starts with
        if p.is_relative_to(copy):
            return str(Path(copies[copy]) / p.relative_to(copy))
    return str(path)


def command_line() -> str:
    """The command line of the run as its user typed it (the program's name, not its path)."""
    given = (_RECORDED_AS.get() or {}).get("command_line")
    if given is not None:
        return given
    if not sys.argv:
        return ""
    program = Path(sys.argv[0]).name
    if program == "__main__.py":  # ``python -m handeye``: the module, as it was typed
        program = "python -m handeye"
    return " ".join([program] + sys.argv[1:])


def provenance(*, inputs_sha256: str | None = None, extra: dict | None = None) -> dict:
    d = {
        "handeye_version": __version__,
        "command_line": command_line(),
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


def remove_stray_temps(folder: str | Path, *, subfolders: tuple = ("thumbnails", "report_files")) -> list[Path]:
    """Remove the temporary files a killed writer left in ``folder``.

    Remove the temporary files a killed writer left in ``folder`` (and its output subfolders):
    the hidden ``.NAME.XXXX.tmp`` files of :func:`atomic_write_bytes`. Call it holding the folder's lock.
    """
    removed = []
    for d in (Path(folder), *(Path(folder) / s for s in subfolders)):
        if not d.is_dir():
            continue
        for p in d.glob(".*" + TEMP_SUFFIX):
            try:
                p.unlink()
                removed.append(p)
            except OSError:
                pass
    return removed


def _first_existing(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


@contextmanager
def new_folders_kept_only_if_used(out: str | Path):
    """Within the block, ``out`` and the parents it is made with are removed again at the end if still empty.

    For a command that makes its output folder before it knows that it will write there (a refusal, a failed
    import, a collection whose devices did not open): an empty folder left behind would block the same command's rerun.
    A folder that existed before, or holds anything, stays.
    """
    missing, p = [], Path(out)
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    try:
        yield
    finally:
        for folder in missing:  # deepest first
            try:
                folder.rmdir()  # only an empty folder
            except OSError:
                break


def check_out_dir(path: str | Path, *, option: str = "--out") -> Path:
    """``path`` as an output folder that can be created and written, checked before any work.

    Not a file, not under a file, writable (a probe file is created and removed). OutputError naming
    the folder and ``option`` otherwise. Creates the folder.
    """
    path = Path(path)
    hint = f"pass another folder with {option}"
    if path.exists() and not path.is_dir():
        raise OutputError(
            f"{option} is a file, not a folder",
            path=path,
            expected="a folder (or a new name)",
            received="a file" if path.is_file() else "not a regular folder",
            hint=hint,
        )
    anchor = _first_existing(path)
    if not anchor.is_dir():
        raise OutputError(
            f"{option} lies under a file",
            path=path,
            expected="a folder path",
            received=f"{anchor} is a file",
            hint=hint,
        )
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".handeye-probe.", suffix=TEMP_SUFFIX, dir=path)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise OutputError(
            f"{option} cannot be written ({e.strerror or e})",
            path=path,
            expected="a writable folder",
            hint=hint + ", or fix its permissions",
        ) from None
    return path


def _pid_alive(pid: int) -> bool:
    """Whether process ``pid`` still runs.

    A zombie (ended, not yet reaped: an orphan whose new parent does not reap it promptly, as some container
    init processes do) has ended and holds nothing; a process whose main thread has ended while others run
    shows the same state and still runs.
    """
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    try:
        status = dict(
            line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line
        )
        state, threads = status["State"].split()[0], int(status["Threads"])
    except (OSError, KeyError, IndexError, ValueError):  # no /proc (another system), or it ended meanwhile
        return True if not Path("/proc/self").exists() else Path(f"/proc/{pid}").exists()
    return state not in ("Z", "X") or threads > 1


@contextmanager
def _folder_guard(folder: Path):
    """The folder itself locked (``flock`` on its descriptor) while a lock file in it is read and written.

    Without it, two runs starting together could both see no holder (or the same stale one) and both take the
    lock. Held for microseconds; where there is no ``fcntl`` (Windows), or the folder cannot be opened, nothing.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        yield  # the lock file's own open reports the folder's fault
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the flock


class FolderLock:
    """One writer per output folder: ``FOLDER/.handeye.lock`` holds the pid of the run writing there.

    A second run into the folder is refused (OutputError naming the holder's pid) while that pid lives;
    a lock whose pid is gone (the run was killed) is stale and taken over. Used as a context manager.
    """

    def __init__(self, folder: str | Path, *, option: str = "--out"):
        self.path = Path(folder) / LOCK_NAME
        self.option = option
        self._held = False

    def acquire(self) -> "FolderLock":
        with _folder_guard(self.path.parent):  # one process at a time reads, takes over and writes the lock
            return self._acquire()

    def _acquire(self) -> "FolderLock":
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is not None and holder != os.getpid() and _pid_alive(holder):
                    raise OutputError(
                        f"{self.option} is in use by another handeye run (pid {holder})",
                        path=self.path.parent,
                        expected="one run per output folder",
                        hint=f"wait for pid {holder} to finish, or pass another folder with {self.option}",
                    ) from None
                try:  # stale: its run was killed (or the file is empty or damaged)
                    self.path.unlink()
                except FileNotFoundError:
                    pass
                continue
            except OSError as e:
                raise OutputError(
                    f"{self.option} cannot be locked ({e.strerror or e})",
                    path=self.path.parent,
                    hint=f"pass another folder with {self.option}",
                ) from None
            with os.fdopen(fd, "w") as f:
                f.write(f"{os.getpid()}\n")
            self._held = True
            return self
        raise OutputError(
            f"{self.option} is being locked by other runs at the same time",
            path=self.path.parent,
            hint="run one calibration per output folder",
        )

    def _holder(self):
        try:
            return int(self.path.read_text().split()[0])
        except (OSError, ValueError, IndexError):
            return None

    def release(self) -> None:
        if self._held:
            self._held = False
            with _folder_guard(self.path.parent):
                if self._holder() == os.getpid():
                    try:
                        self.path.unlink()
                    except FileNotFoundError:
                        pass

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()


def file_sha256(path: str | Path) -> str:
    """SHA-256 of one file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def inputs_record(paths, *, base: str | Path | None = None, digests: dict | None = None) -> list[dict]:
    """Every input file read, once each in the given order: ``{"path", "sha256", "bytes"}``.

    Every input file read, once each in the given order: ``{"path", "sha256", "bytes"}`` (paths
    relative to ``base`` when inside it) for result.json's ``provenance.inputs``. ``digests``: absolute path ->
    SHA-256 of the bytes already read (the images, hashed as they were decoded); other files are read here.
    """
    digests = digests or {}
    out, seen = [], set()
    for p in paths:
        p = Path(p)
        key = os.path.abspath(p)
        if key in seen or not p.is_file():
            continue
        seen.add(key)
        name = str(p)
        if base is not None:
            try:
                name = str(Path(key).relative_to(os.path.abspath(base)))
            except ValueError:
                pass
        out.append({"path": name, "sha256": digests.get(key) or file_sha256(p), "bytes": p.stat().st_size})
    return out


def decode_text(data: bytes, *, path: str | Path, what: str = "text file") -> str:
    """Bytes of a text input file as str: UTF-8, UTF-16 with a BOM, or Latin-1.

    Bytes of a text input file as str: UTF-8 (a BOM is dropped), UTF-16 with a BOM, or Latin-1 when
    the bytes are not UTF-8 (a warning names the file); UTF-16 without a BOM is an InputError naming it.
    """
    import codecs
    import logging

    if data.startswith(codecs.BOM_UTF8):
        data = data[len(codecs.BOM_UTF8) :]
    elif data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        try:
            return data.decode("utf-16")
        except UnicodeDecodeError:
            raise InputError(
                f"{what} starts like UTF-16 but does not decode", path=path, hint="save it as UTF-8 text"
            ) from None
    if data.count(b"\x00") > len(data) // 4:  # text never holds NULs; UTF-16 of ASCII is half NULs
        raise InputError(
            f"{what} is UTF-16 without a byte-order mark (or binary)",
            path=path,
            expected="UTF-8 text",
            hint="save it as UTF-8 text",
        )
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        pass
    logging.getLogger(__name__).warning("%s: not UTF-8; read as Latin-1 (save it as UTF-8 to silence this)", path)
    return data.decode("latin-1")


def read_text(path: str | Path, *, what: str = "text file", max_bytes: int = 64 << 20) -> str:
    """The text of an input file.

    The text of an input file (see :func:`decode_text`); InputError naming the file when it is missing,
    not a regular file (a folder, a device, a pipe: never opened), unreadable or larger than ``max_bytes``.
    """
    import stat

    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{what} not found", path=path) from None
    except OSError as e:
        raise InputError(f"cannot read {what} ({e.strerror})", path=path) from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(
            f"{what} is not a regular file", path=path, received=file_kind(st.st_mode), expected="a text file"
        )
    if st.st_size > max_bytes:
        raise InputError(
            f"{what} is too large for a text input",
            path=path,
            received=f"{st.st_size} bytes",
            expected=f"at most {max_bytes} bytes",
        )
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except OSError as e:
        raise InputError(f"cannot read {what} ({e.strerror})", path=path) from None
    return decode_text(data, path=path, what=what)


def file_kind(mode: int) -> str:
    """What a stat mode is, for messages: a folder, a character device, a named pipe, ..."""
    import stat

    for test, name in (
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a named pipe"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISREG, "a regular file"),
    ):
        if test(mode):
            return name
    return "not a regular file"
