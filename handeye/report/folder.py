"""The result folder the report is built from, read once: nothing else is read.

``result.json`` (required), ``observations.json`` (per-view corners and fits, optional) and
``thumbnails/<view_id>.jpg`` (small JPEGs written with the result, optional). The session and its
images are never opened: a report rebuilt on another machine shows the same thing.
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
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"not valid JSON ({e})", path=p, hint="re-run handeye calibrate") from None
    if not isinstance(d, dict):
        raise InputError("not a JSON object", path=p, hint="re-run handeye calibrate")
    return d


def read_result_folder(path: str | Path) -> ResultFolder:
    """Read a folder written by ``handeye calibrate`` (or the result.json inside it)."""
    path = Path(path)
    if path.is_file():
        path = path.parent
    res_path = path / "result.json"
    if not res_path.is_file():
        raise InputError("no result.json in this folder", path=path,
                         hint="pass the folder written by handeye calibrate --out")
    res = _read_json(res_path)
    obs_path = path / "observations.json"
    obs = _matching_observations(res, _read_json(obs_path)) if obs_path.is_file() else {}
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
    """observations.json restricted to the views of this result (a stale file from an earlier run of
    another session in the same folder must not leak into the report)."""
    ids = {str(v.get("id")) for v in res.get("views") or []}
    if not ids or (obs.get("mode") and res.get("mode") and obs.get("mode") != res.get("mode")):
        return {}
    out = dict(obs)
    out["views"] = {str(k): v for k, v in (obs.get("views") or {}).items() if str(k) in ids}
    return out
