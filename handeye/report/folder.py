"""The result folder the report is built from, read once: nothing else is read.

``result.json`` (required), ``observations.json`` (per-view corners and fits, optional) and
``thumbnails/<view_id>.jpg`` (small JPEGs written with the result, optional). The session and its
images are never opened: a report rebuilt on another machine shows the same thing.

result.json is checked once (:func:`check_result`, by :mod:`handeye.contract`): a damaged or foreign
file is an InputError naming the field, never a crash deep in the report. observations.json is used
only when it belongs to the same run (its ``run_id`` equals result.json's; a run killed after writing
it but before result.json leaves the older result with a newer observations.json, then ignored).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError

THUMBNAILS_DIR = "thumbnails"


@dataclass(frozen=True)
class ResultFolder:
    path: Path
    result: dict
    observations: dict  # {} when the folder has none, or one of another session / mode
    thumbnails: dict = field(default_factory=dict)  # view id -> JPEG bytes


def _read_json(p: Path) -> dict:
    try:
        d = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise InputError(
            f"not valid JSON ({type(e).__name__}: {str(e)[:80]})", path=p, hint="re-run handeye calibrate"
        ) from None
    except OSError as e:
        raise InputError(f"cannot read the file ({e.strerror})", path=p, hint="re-run handeye calibrate") from None
    if not isinstance(d, dict):
        raise InputError("not a JSON object", path=p, hint="re-run handeye calibrate")
    return d


def read_result_folder(path: str | Path) -> ResultFolder:
    """Read a folder written by ``handeye calibrate``, or one result file in it.

    ``path``: the folder, its result.json, or another result of it (``result.last-good.json``,
    ``result.previous.json``), whose report uses the folder's observations and thumbnails only when they are of
    its own run (they are result.json's).
    """
    path = Path(path)
    res_path = path if path.is_file() else path / "result.json"
    folder = res_path.parent
    if not res_path.is_file():
        raise InputError(
            "no result.json in this folder", path=path, hint="pass the folder written by handeye calibrate --out"
        )
    res = check_result(_read_json(res_path), path=res_path)
    obs_path = folder / "observations.json"
    obs = _read_json(obs_path) if obs_path.is_file() else None
    if res_path.name != "result.json" and not (obs and _matching_observations(res, obs)):
        return ResultFolder(folder, res, {})  # another run's observations and thumbnails: none of them
    return _assemble(folder, res, obs)


def result_folder(path: str | Path, result: dict, observations: dict | None = None) -> ResultFolder:
    """The result folder ``path`` with result.json's and observations.json's contents given.

    The result folder ``path`` with result.json's and observations.json's contents given (as just
    written there: nothing is read again but the thumbnails), checked as :func:`read_result_folder`
    checks them.
    """
    path = Path(path)
    return _assemble(path, check_result(result, path=path / "result.json"), observations)


def _assemble(path: Path, res: dict, obs: dict | None) -> ResultFolder:
    obs = _matching_observations(res, obs) if obs is not None else {}
    ids = {str(v.get("id")) for v in res.get("views") or []}
    thumbs = {}
    tdir = path / THUMBNAILS_DIR
    if tdir.is_dir():
        for vid in ids:
            p = tdir / f"{vid}.jpg"
            if p.parent == tdir and p.is_file():  # a view id never reaches outside the folder
                thumbs[vid] = p.read_bytes()
    return ResultFolder(path, res, obs, thumbs)


def _matching_observations(res: dict, obs: dict) -> dict:
    """observations.json restricted to the views of this result.

    observations.json restricted to the views of this result (a stale file from an earlier run of
    another session in the same folder must not leak into the report).
    """
    ids = {str(v.get("id")) for v in res.get("views") or []}
    if not ids or (obs.get("mode") and res.get("mode") and obs.get("mode") != res.get("mode")):
        return {}
    if res.get("run_id") is not None and obs.get("run_id") != res.get("run_id"):
        return {}  # another run's observations (a run killed between the two files)
    if not isinstance(obs.get("views") or {}, dict):
        return {}
    out = dict(obs)
    out["views"] = {str(k): v for k, v in (obs.get("views") or {}).items() if str(k) in ids}
    return out


def check_result(res: dict, *, path: Path) -> dict:
    """result.json's structure as the report reads it: InputError naming the first damaged field.

    The check is the contract's (:func:`handeye.contract.validate_result`; a file without its version key is
    read as the current version, as the report always has); the dict is returned as it is.
    """
    from ..contract import validate_result

    validate_result(res, source=str(path), require_version=False, partial=False)
    return res
