"""Reading sessions from disk: the only code that reads inputs.

- :mod:`.vendor`: the vendor folder as it is (config.yaml, poses.txt, numbered images);
- :mod:`.native`: handeye's session.yaml (any pose format, optional intrinsics, view records);
- :mod:`.target_spec`: the ``target:`` section -> a target spec;
- :mod:`.fields`: validated fields, unit plausibility, where a session's files are;
- :mod:`.raw`: the lenient reading for the diagnostics (raw pose numbers, no unit checks);
- :mod:`.importers`: other tools' layouts (ViSP, industrial_calibration) -> session.yaml.

Strict loading validates everything once; errors name the file (and line) and what to do. Poses are
converted to ``T_base_end`` (metres) at this boundary. See docs/session_format.md.
"""
from __future__ import annotations

from pathlib import Path

from ..records import Session
from .fields import locate_session
from .native import load_native_session
from .vendor import load_vendor_session


def load_session(path: str | Path, *, mode: str | None = None, allow_outside: bool = False) -> Session:
    """Load a session folder (native ``session.yaml`` or vendor ``poses.txt``), or a session.yaml path.

    ``mode`` overrides the mode stated in the session (the CLI's ``--mode``). ``allow_outside`` lets a
    native session's image and pose-file paths leave the session folder (and its ``image_folder``);
    by default such a path is an InputError. A vendor session's images are always its folder's.
    """
    kind, p = locate_session(path)
    if kind == "native":
        return load_native_session(p, mode=mode, allow_outside=allow_outside)
    return load_vendor_session(p, mode=mode)
