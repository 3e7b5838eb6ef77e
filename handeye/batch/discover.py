"""Find the sessions under a root folder, group them by install and give each its time.

A session is a folder holding ``session.yaml`` or ``poses.txt``, or a cell (``cell.yaml``: the sessions of
several cameras of one arm, calibrated together as one job; its camera folders are part of it). Its install
is ``install:`` in its ``session.yaml`` (a cell's ``cell.yaml``), else its first folder under the root
(``ROOT/<install>/<session>/``), else the root's own name; its time is ``time:``, else the first ``t_image``,
else a date in its folder name, else the newest modification time of its files. A session with
``verify_against:`` is a verification, not a calibration. Names become folder names under OUT, made safe and
unique.

See docs/fleet.md and, for faults in one session, docs/batch.md.
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError
from ..session.fields import CELL_FILE

log = logging.getLogger(__name__)

#: the install of a root that is itself a session (and names no install)
DEFAULT_INSTALL = "default"


_DATE_RE = re.compile(r"(?<!\d)(\d{4})-?(\d{2})-?(\d{2})(?:[T_ -]?(\d{2}):?(\d{2})(?::?(\d{2}))?)?(?!\d)")


@dataclass(frozen=True)
class SessionJob:
    """One session of the batch.

    Where it is, its install, its name (a path under the install's output folder, ``/``-separated), its
    time (ISO 8601 UTC, or None) and where that came from.

    ``warnings``: what discovery passed over (a time that is not one); ``error``: why the session cannot
    run at all (the batch records it as a failed session without running it).
    """

    path: Path
    install: str
    name: str
    time_utc: str | None
    time_source: str
    layout: str  # native | vendor | cell
    verify_against: str | None = None  # session.yaml verify_against: the installed result this session checks
    warnings: tuple = ()
    error: str | None = None

    @property
    def key(self) -> str:
        """``install/name``: the session's folder under OUT."""
        return f"{self.install}/{self.name}"


@dataclass(frozen=True)
class SkippedFolder:
    """A folder under the root that discovery did not enter, and why.

    A link loop, a second link to a folder already reached, a link to nothing, a folder that cannot be listed.
    """

    path: Path
    reason: str


@dataclass(frozen=True)
class Discovery:
    """The sessions under a root (:class:`SessionJob`, sorted) and the folders skipped on the way."""

    jobs: list
    skipped: list


def safe_component(name: str) -> str:
    """``name`` as one folder name (see the module docstring)."""
    s = re.sub(r"[^A-Za-z0-9._-]", "_", str(name).strip()) or "_"
    if set(s) == {"."}:
        s = s.replace(".", "_")
    return s


def walk_sessions(root: Path) -> tuple[list[tuple[Path, str]], list[SkippedFolder]]:
    """(folder, layout) of every session under ``root`` and the folders skipped, both sorted by path.

    ``root`` itself may be a session; folders are named by the path they were reached by (module docstring).
    """
    root = Path(root)
    found: list[tuple[Path, str]] = []
    skipped: list[SkippedFolder] = []
    reached: dict[str, Path] = {}  # real path -> the path it was first reached by
    links: list[tuple[Path, tuple]] = []  # links met on the walk of the real folders, with their parents' real paths

    SESSION_FILES = ("session.yaml", "poses.txt", CELL_FILE)

    def visit(folder: Path, parents: tuple, *, follow: bool) -> None:
        real = os.path.realpath(folder)
        if real in parents:
            skipped.append(SkippedFolder(folder, f"a link loop: it leads back to {reached.get(real, real)}"))
            return
        if real in reached:
            skipped.append(SkippedFolder(folder, f"the same folder as {reached[real]} (reached twice through a link)"))
            return
        reached[real] = folder
        try:
            entries = sorted(os.scandir(folder), key=lambda e: e.name)
        except OSError as e:
            skipped.append(SkippedFolder(folder, f"cannot be listed ({e.strerror or e})"))
            return
        names = {e.name for e in entries if _is(e.is_file)}
        layout = "native" if "session.yaml" in names else ("vendor" if "poses.txt" in names else None)
        if CELL_FILE in names:  # a cell: its camera folders are its own, not sessions of their own
            layout = "cell"
        if layout is not None:  # a session's sub-folders (images, view records) are part of it
            found.append((folder, layout))
            return
        for entry in entries:
            if entry.name.startswith("."):  # hidden (.git, .cache): passed over, said when it holds a session
                if _is(entry.is_dir) and any(os.path.isfile(os.path.join(entry.path, n)) for n in SESSION_FILES):
                    skipped.append(SkippedFolder(Path(entry.path), "a hidden folder (its name starts with a dot)"))
                continue
            path = Path(entry.path)
            if entry.is_symlink():
                if not os.path.exists(path):
                    skipped.append(SkippedFolder(path, f"a link to nothing ({os.readlink(path)} does not exist)"))
                elif _is(entry.is_dir):
                    if follow:
                        visit(path, parents + (real,), follow=True)
                    else:
                        links.append((path, parents + (real,)))
            elif _is(entry.is_dir):
                visit(path, parents + (real,), follow=follow)

    visit(root, (), follow=False)
    for path, parents in links:  # after every real folder: a session reached both ways keeps its real name
        visit(path, parents, follow=True)
    for s in skipped:  # the command says them itself
        log.info("%s: skipped: %s", s.path, s.reason)
    return sorted(found, key=lambda fl: str(fl[0])), sorted(skipped, key=lambda s: str(s.path))


def _is(test) -> bool:
    """``DirEntry.is_file`` / ``is_dir`` (links followed), False where the entry cannot be looked at."""
    try:
        return test()
    except OSError:
        return False


def find_session_folders(root: Path) -> list[tuple[Path, str]]:
    """(folder, layout) of every session under ``root`` (``root`` itself included), sorted by path."""
    return walk_sessions(root)[0]


def discover(root) -> list[SessionJob]:
    """Every session under ``root`` as a :class:`SessionJob`, sorted by install, time and name."""
    return discover_fleet(root).jobs


def discover_fleet(root) -> Discovery:
    """Every session under ``root`` and the folders skipped on the way.

    Sessions as :class:`SessionJob`, sorted by install, time and name; skipped folders as
    :class:`SkippedFolder`.
    """
    root = Path(root)
    if not root.is_dir():
        raise InputError(
            "batch root not found or not a folder",
            path=root,
            hint="pass the folder that holds the sessions (ROOT/<install>/<session>/)",
        )
    jobs, taken = [], set()
    folders, skipped = walk_sessions(root)
    for folder, layout in folders:
        warnings: list[str] = []
        yaml_name = CELL_FILE if layout == "cell" else "session.yaml"
        meta = _session_yaml(folder, warnings, yaml_name) if layout != "vendor" else {}
        rel = folder.relative_to(root).parts
        if isinstance(meta.get("install"), (str, int, float)) and meta["install"] != "":
            install = safe_component(meta["install"])
            name = "/".join(safe_component(p) for p in rel[1:]) if len(rel) > 1 else safe_component(folder.name)
        else:
            if meta.get("install") not in (None, ""):
                warnings.append(f"install {_short(meta['install'])} is not a name; grouped by its folder")
            if len(rel) >= 2:
                install, name = safe_component(rel[0]), "/".join(safe_component(p) for p in rel[1:])
            elif len(rel) == 1:
                install, name = safe_component(root.resolve().name), safe_component(rel[0])
            else:
                install, name = DEFAULT_INSTALL, safe_component(folder.resolve().name)
        base, k = name, 2
        while (install, name) in taken:
            name, k = f"{base}~{k}", k + 1
        taken.add((install, name))
        t, src = session_time(folder, meta, warnings)
        against, error = (meta.get("verify_against") if layout != "cell" else None), None
        if against in (None, ""):
            against = None
        elif not isinstance(against, str):
            error = (
                f"{folder / 'session.yaml'}: verify_against must be a path (the installed result folder or its "
                f"result.json, relative to the session); got {_short(against)}"
            )
            against = None
        else:
            against = str((folder / against).resolve())
        for w in warnings:
            log.warning("%s: %s", folder, w)
        jobs.append(
            SessionJob(
                path=folder.resolve(),
                install=install,
                name=name,
                time_utc=t,
                time_source=src,
                layout=layout,
                verify_against=against,
                warnings=tuple(warnings),
                error=error,
            )
        )
    jobs.sort(key=lambda j: (j.install, j.time_utc or "", j.name))
    log.info("%d sessions in %d installs under %s", len(jobs), len({j.install for j in jobs}), root)
    return Discovery(jobs=jobs, skipped=skipped)


def _short(value) -> str:
    """``repr(value)`` cut to one short line, for a warning."""
    text = " ".join(repr(value).split())
    return text if len(text) <= 60 else text[:57] + "..."


def _session_yaml(folder: Path, warnings: list, name: str = "session.yaml") -> dict:
    """The top-level mapping of ``session.yaml`` (a cell: ``cell.yaml``; its ``install`` and ``time`` alike).

    {} when it does not parse, with a warning in ``warnings``: the calibration then reports why, the batch
    only needs the install and the time.
    """
    import yaml

    try:
        d = yaml.safe_load((folder / name).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError, ValueError, OverflowError) as e:  # ValueError: a bad date
        # its install, time and verify_against are lost: grouped by its path, run as a calibration, which names
        # the file's fault in its own record
        warnings.append(f"{name} not read for the batch ({' '.join(str(e).split())}); grouped by its folder")
        return {}
    if d is not None and not isinstance(d, dict):
        warnings.append(f"{name} is not a mapping; grouped by its folder")
    return d if isinstance(d, dict) else {}


def _iso(t: _dt.datetime) -> str:
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.timezone.utc)
    return t.astimezone(_dt.timezone.utc).isoformat(timespec="seconds")


def session_time(folder: Path, meta: dict, warnings: list | None = None) -> tuple[str | None, str]:
    """(ISO 8601 UTC time, source) of a session (see the module docstring).

    A value passed over is said in ``warnings`` (a list the caller keeps).
    """
    warnings = [] if warnings is None else warnings
    t = meta.get("time")
    if isinstance(t, _dt.datetime):
        return _iso(t), "session.yaml time"
    if isinstance(t, _dt.date):
        return _iso(_dt.datetime(t.year, t.month, t.day)), "session.yaml time"
    if t is not None:
        try:
            return _iso(_dt.datetime.fromisoformat(t.strip())), "session.yaml time"
        except (AttributeError, ValueError, OverflowError):
            warnings.append(f"session.yaml time {_short(t)} is not an ISO 8601 time; the time is taken from elsewhere")
    views = meta.get("views")
    stamps, bad = [], []
    for v in views if isinstance(views, list) else []:
        s = v.get("t_image") if isinstance(v, dict) else None
        if s is None:
            continue
        if isinstance(s, (int, float)) and not isinstance(s, bool) and _stamp(s) is not None:
            stamps.append(float(s))
        else:
            bad.append(s)
    if bad:
        warnings.append(
            f"t_image {_short(bad[0])}{f' (and {len(bad) - 1} more)' if len(bad) > 1 else ''} is not a time "
            "(seconds since 1970); those stamps are passed over for the session's time"
        )
    first = _stamp(min(stamps)) if stamps else None
    if first is not None:  # every stamp kept converts (checked above)
        return _iso(first), "t_image"
    m = _DATE_RE.search(folder.resolve().name)  # the root itself given as "." has the name ""
    if m:
        y, mo, d, hh, mm, ss = (int(g) if g else 0 for g in m.groups())
        try:
            return _iso(_dt.datetime(y, mo, d, hh, mm, ss)), "folder name"
        except ValueError:
            pass
    try:
        newest = _stamp(max(p.stat().st_mtime for p in folder.iterdir() if p.is_file()))
    except (OSError, ValueError):
        newest = None
    if newest is None:
        return None, "none"
    return _iso(newest), "file time"


def _stamp(seconds: float) -> _dt.datetime | None:
    """``seconds`` since 1970 as a UTC time, None when it is not one this platform can represent."""
    try:
        return _dt.datetime.fromtimestamp(float(seconds), _dt.timezone.utc)
    except (OverflowError, OSError, ValueError):
        return None
