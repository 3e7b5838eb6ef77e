"""Find the sessions under a root folder and group them by install.

A session is a folder holding ``session.yaml`` (native layout) or ``poses.txt`` (vendor layout); the
search does not descend into a session folder. Each session belongs to one install:

1. ``install: NAME`` at the top of its ``session.yaml``, when given;
2. else the first folder under the root: ``ROOT/<install>/<session>/`` (deeper sessions keep their
   whole path below the install as their name: ``ROOT/cell-07/2026/03-01`` is install ``cell-07``,
   session ``2026/03-01``);
3. else, for a session directly in ROOT (``ROOT/<session>/``), ROOT's own folder name: ROOT is then
   one install's folder;
4. else (ROOT is itself a session) the install ``default``.

The session's time orders an install's sessions for the drift and the trend: ``time:`` in
``session.yaml`` (ISO 8601), else the earliest ``t_image`` of its inline views, else a date in its
folder name (``2026-03-01``, ``20260301`` with an optional ``_1430`` / ``T14:30``), else the newest
modification time of its files. ``time_source`` says which.

A session whose ``session.yaml`` says ``verify_against: PATH`` (an installed result folder or its result.json,
relative to the session folder) is a check of that installed calibration: the batch runs ``handeye verify`` on it
(:func:`handeye.batch.child.run_verify`) instead of a calibration.

Install and session names become folder names under OUT: characters other than letters, digits,
``.``, ``_`` and ``-`` are replaced by ``_`` (a name made only of dots is refused), and two sessions
that would land in one folder get ``~2``, ``~3`` appended.
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError

log = logging.getLogger(__name__)

#: the install of a root that is itself a session (and names no install)
DEFAULT_INSTALL = "default"

_DATE_RE = re.compile(r"(?<!\d)(\d{4})-?(\d{2})-?(\d{2})(?:[T_ -]?(\d{2}):?(\d{2})(?::?(\d{2}))?)?(?!\d)")


@dataclass(frozen=True)
class SessionJob:
    """One session of the batch: where it is, its install, its name.

    One session of the batch: where it is, its install, its name (a path under the install's
    output folder, ``/``-separated), its time (ISO 8601 UTC, or None) and where that came from.
    """

    path: Path
    install: str
    name: str
    time_utc: str | None
    time_source: str
    layout: str  # native | vendor
    verify_against: str | None = None  # session.yaml verify_against: the installed result this session checks

    @property
    def key(self) -> str:
        """``install/name``: the session's folder under OUT."""
        return f"{self.install}/{self.name}"


def safe_component(name: str) -> str:
    """``name`` as one folder name (see the module docstring)."""
    s = re.sub(r"[^A-Za-z0-9._-]", "_", str(name).strip()) or "_"
    if set(s) == {"."}:
        s = s.replace(".", "_")
    return s


def find_session_folders(root: Path) -> list[tuple[Path, str]]:
    """(folder, layout) of every session under ``root`` (``root`` itself included), sorted by path."""
    found = []
    for folder, dirs, files in os.walk(root, followlinks=False):
        names = set(files)
        layout = "native" if "session.yaml" in names else ("vendor" if "poses.txt" in names else None)
        if layout is not None:
            found.append((Path(folder), layout))
            dirs[:] = []  # a session's sub-folders (images, view records) are part of it
        else:
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
    return sorted(found, key=lambda fl: str(fl[0]))


def discover(root) -> list[SessionJob]:
    """Every session under ``root`` as a :class:`SessionJob`, sorted by install, time and name."""
    root = Path(root)
    if not root.is_dir():
        raise InputError(
            "batch root not found or not a folder",
            path=root,
            hint="pass the folder that holds the sessions (ROOT/<install>/<session>/)",
        )
    jobs, taken = [], set()
    for folder, layout in find_session_folders(root):
        meta = _session_yaml(folder) if layout == "native" else {}
        rel = folder.relative_to(root).parts
        if meta.get("install") not in (None, ""):
            install = safe_component(meta["install"])
            name = "/".join(safe_component(p) for p in rel[1:]) if len(rel) > 1 else safe_component(folder.name)
        elif len(rel) >= 2:
            install, name = safe_component(rel[0]), "/".join(safe_component(p) for p in rel[1:])
        elif len(rel) == 1:
            install, name = safe_component(root.resolve().name), safe_component(rel[0])
        else:
            install, name = DEFAULT_INSTALL, safe_component(folder.resolve().name)
        base, k = name, 2
        while (install, name) in taken:
            name, k = f"{base}~{k}", k + 1
        taken.add((install, name))
        t, src = session_time(folder, meta)
        against = meta.get("verify_against")
        if against not in (None, ""):
            if not isinstance(against, str):
                raise InputError(
                    "verify_against must be a path",
                    path=folder / "session.yaml",
                    received=repr(against),
                    expected="the installed result folder or its result.json (relative to the session)",
                )
            against = str((folder / against).resolve())
        jobs.append(
            SessionJob(
                path=folder.resolve(),
                install=install,
                name=name,
                time_utc=t,
                time_source=src,
                layout=layout,
                verify_against=against or None,
            )
        )
    jobs.sort(key=lambda j: (j.install, j.time_utc or "", j.name))
    log.info("%d sessions in %d installs under %s", len(jobs), len({j.install for j in jobs}), root)
    return jobs


def _session_yaml(folder: Path) -> dict:
    """The top-level mapping of ``session.yaml``.

    The top-level mapping of ``session.yaml`` ({} when it does not parse: the calibration then
    reports why, the batch only needs the install and the time).
    """
    import yaml

    try:
        d = yaml.safe_load((folder / "session.yaml").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as e:
        # its install, time and verify_against are lost: grouped by its path, run as a calibration, which names
        # the file's fault in its own record
        log.warning("%s: not read for the batch (%s); grouped by its folder", folder / "session.yaml", e)
        return {}
    return d if isinstance(d, dict) else {}


def _iso(t: _dt.datetime) -> str:
    if t.tzinfo is None:
        t = t.replace(tzinfo=_dt.timezone.utc)
    return t.astimezone(_dt.timezone.utc).isoformat(timespec="seconds")


def session_time(folder: Path, meta: dict) -> tuple[str | None, str]:
    """(ISO 8601 UTC time, source) of a session (see the module docstring)."""
    t = meta.get("time")
    if isinstance(t, _dt.datetime):
        return _iso(t), "session.yaml time"
    if isinstance(t, _dt.date):
        return _iso(_dt.datetime(t.year, t.month, t.day)), "session.yaml time"
    if isinstance(t, str):
        try:
            return _iso(_dt.datetime.fromisoformat(t.strip())), "session.yaml time"
        except ValueError:
            log.warning("%s: session.yaml time %r is not ISO 8601; using the next source", folder, t)
    raw_stamps = [v.get("t_image") for v in (meta.get("views") or []) if isinstance(v, dict)]
    stamps = [float(s) for s in raw_stamps if isinstance(s, (int, float)) and not isinstance(s, bool)]
    if stamps:
        return _iso(_dt.datetime.fromtimestamp(min(stamps), _dt.timezone.utc)), "t_image"
    m = _DATE_RE.search(folder.name)
    if m:
        y, mo, d, hh, mm, ss = (int(g) if g else 0 for g in m.groups())
        try:
            return _iso(_dt.datetime(y, mo, d, hh, mm, ss)), "folder name"
        except ValueError:
            pass
    try:
        newest = max(p.stat().st_mtime for p in folder.iterdir() if p.is_file())
    except (OSError, ValueError):
        return None, "none"
    return _iso(_dt.datetime.fromtimestamp(newest, _dt.timezone.utc)), "file time"
