"""The contract between the commands: handeye's files as typed, versioned models, one reader, one writer.

result.json (and observations.json, verify.json, batch.json) are pydantic v2 models (:mod:`.models`),
chosen for three things a hand-written check lacks: typed models whose accessors the readers use
(``T_x``, ``cov_x``, ``camera``), a JSON schema generated from the same models (``docs/*.schema.json``,
``python -m handeye.contract``), and errors that carry the field's path (``intrinsics.dist.k1``).
:func:`read_result` is THE reader: a damaged or foreign field is one :class:`~handeye.errors.InputError`
(exit 2) naming the file, the field, what was expected and what was found. :func:`write_result` is THE
writer: it validates before the atomic write, so a result handeye cannot read back is never written.
Versions: ``handeye_result`` (result.json's version key). An older version is migrated
(:data:`MIGRATIONS`) or refused in one line; a newer one is refused in one line.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Callable, Optional, Union

from pydantic import BaseModel, ValidationError

from ..errors import InputError, clip
from .fields import short
from .models import (
    OBSERVATIONS_VERSION,
    OLDEST_RESULT_VERSION,
    RESULT_VERSION,
    VERIFY_VERSION,
    Result,
)
from .records import BatchRecord, Observations, Verify

__all__ = [
    "MIGRATIONS",
    "OBSERVATIONS_VERSION",
    "RESULT_VERSION",
    "SCHEMAS",
    "VERIFY_VERSION",
    "BatchRecord",
    "Observations",
    "Result",
    "Verify",
    "read_result",
    "single_camera",
    "read_json_object",
    "schema",
    "validate",
    "validate_result",
    "check_written",
    "write_validated",
    "write_result",
]

#: result.json version n -> a function that turns its dict into version n + 1 (no version before 1 was
#: ever written, so there is none yet; a version below the oldest with a migration is refused)
MIGRATIONS: dict[int, Callable[[dict], dict]] = {}

#: file name -> (model, its schema's file name under docs/)
SCHEMAS: dict[str, tuple[type[BaseModel], str]] = {
    "result.json": (Result, "result.schema.json"),
    "observations.json": (Observations, "observations.schema.json"),
    "verify.json": (Verify, "verify.schema.json"),
    "batch.json": (BatchRecord, "batch.schema.json"),
}

_HINT = "the file was edited or damaged: restore it or calibrate again"


def read_json_object(path: Union[str, Path], *, hint: str = "re-run handeye calibrate") -> dict:
    """A JSON file's top-level object; InputError (one line, naming the file) for anything else."""
    path = Path(path)
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(
            "file not found", path=path, hint="run handeye calibrate first or pass the result folder"
        ) from None
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError) as e:
        raise InputError(f"not valid JSON ({type(e).__name__}: {clip(e, 80)})", path=path, hint=hint) from None
    except OSError as e:
        raise InputError(f"cannot read the file ({e.strerror or type(e).__name__})", path=path, hint=hint) from None
    if not isinstance(d, dict):
        raise InputError("not a JSON object", path=path, hint=hint)
    return d


def _field(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif isinstance(part, str) and not any(c in part for c in "[]()"):
            out += ("." if out else "") + part
    return out


#: pydantic's words for the expected type -> a person's
_WORDS = {
    "a valid dictionary": "a mapping",
    "a valid string": "a text",
    "a valid list": "a list",
    "a valid boolean": "true or false",
    "a valid integer": "an integer",
}


def _error(e: ValidationError, path: str, name: str) -> InputError:
    """The first of a ValidationError's errors as one InputError naming the field."""
    err = e.errors(include_url=False)[0]
    ctx = err.get("ctx") or {}
    where = _field(err["loc"])  # a whole-model check names its field relative to the model at loc
    field = (f"{where}.{ctx['field']}" if where else ctx["field"]) if ctx.get("field") else where or "(top level)"
    if err["type"] == "damaged":
        problem, expected = ctx["problem"], ctx["expected"]
    elif err["type"] == "missing":
        problem, expected = "is missing", "the field (it is required)"
    else:
        problem = f"is {short(err.get('input'))}"
        expected = str(err["msg"]).removeprefix("Input should be ").removeprefix("Value error, ")
        expected = re.sub(r" or instance of \w+$", "", expected)
        expected = _WORDS.get(expected, expected)
    return InputError(f"damaged: {field} {problem}", path=path, expected=expected, code=f"{name}_damaged", hint=_HINT)


def validate(model: type[BaseModel], d: dict, *, source: str, name: str, partial: bool = False) -> BaseModel:
    """``d`` validated as ``model``: the model, or InputError naming the first damaged field.

    ``partial``: ``d`` holds some parts only (a program's dict, not a file): the fields it has are checked,
    the presence of those a complete file must hold is not.
    """
    try:
        return model.model_validate(d, context={"partial": partial})
    except ValidationError as e:
        raise _error(e, source, name) from None
    except (RecursionError, OverflowError, MemoryError) as e:  # nested garbage past what the checks walk
        raise InputError(f"damaged: the file cannot be checked ({type(e).__name__})", path=source, hint=_HINT) from None


def _migrate(d: dict, source: str) -> dict:
    """``d`` at :data:`RESULT_VERSION`: migrated from a known older version, refused otherwise."""
    v = d.get("handeye_result")
    if isinstance(v, bool) or not isinstance(v, int):
        raise InputError(
            f"damaged: handeye_result (the result.json version) is {short(v)}",
            path=source,
            expected=f"an integer, {RESULT_VERSION} for this handeye",
            code="result_damaged",
            hint=_HINT,
        )
    if v > RESULT_VERSION:
        raise InputError(
            f"result.json version {v} is newer than this handeye reads (up to {RESULT_VERSION})",
            path=source,
            code="result_version",
            hint="upgrade handeye to read it",
        )
    if v < OLDEST_RESULT_VERSION and v not in MIGRATIONS:
        raise InputError(
            f"result.json version {v} is older than this handeye reads ({OLDEST_RESULT_VERSION} to {RESULT_VERSION})",
            path=source,
            code="result_version",
            hint="calibrate the session again with this handeye",
        )
    while v < RESULT_VERSION:
        if v not in MIGRATIONS:
            raise InputError(
                f"result.json version {v} has no migration to version {v + 1}",
                path=source,
                code="result_version",
                hint="calibrate the session again with this handeye",
            )
        d = MIGRATIONS[v](dict(d))
        v += 1
        d["handeye_result"] = v
    return d


def validate_result(
    d: dict, *, source: str = "<dict>", require_version: bool = True, partial: Optional[bool] = None
) -> Result:
    """result.json's content checked, migrated from an older version first.

    The model keeps ``d`` as ``raw``. ``require_version=False``: a dict built by a program, not read
    from a file: without ``handeye_result`` it is taken as the current version, and it may hold some
    parts only (each part it holds is checked). ``partial`` says the latter alone (for a reader that shows
    what a file holds, such as the fleet index).
    """
    if not isinstance(d, dict):
        raise InputError("not a JSON object", path=source, hint=_HINT)
    partial = (not require_version) if partial is None else partial
    if "handeye_result" not in d and not require_version:
        d = {"handeye_result": RESULT_VERSION, **d}
    elif "handeye_result" not in d:
        raise InputError(
            "not a handeye result.json (no handeye_result version key)",
            path=source,
            expected="a file written by handeye calibrate",
            hint="pass the result folder of handeye calibrate or its result.json",
        )
    d = _migrate(d, source)
    model = validate(Result, d, source=source, name="result", partial=partial)
    assert isinstance(model, Result), "validate returns the model it was given"
    model._raw = d
    return model


def read_result(path: Union[str, Path], *, partial: bool = False) -> Result:
    """THE reader of result.json (a result folder or the file): the validated model.

    ``model.raw`` is the dict as read. InputError (exit 2) for a missing, unreadable, foreign or damaged file.
    ``partial``: a file written by hand with some parts only (``handeye apply`` needs ``status``, ``mode``
    and X) is read, each part it holds checked (see :func:`validate_result`).
    """
    p = Path(path)
    if p.is_dir():
        p = p / "result.json"
    return validate_result(read_json_object(p), source=str(p), require_version=not partial)


def single_camera(res: Result, camera: Optional[str] = None, *, source: str = "result.json") -> Result:
    """The one-camera result a command works on: ``res`` itself, or camera ``camera`` of a cell.

    A cell without ``camera`` (and with more than one camera), or a name the cell lacks, is one
    InputError naming the cameras; ``camera`` given for a one-camera result is refused the same way.
    """
    if not res.is_cell:
        if camera is not None:
            raise InputError(
                f"--camera {camera!r}: the result is one camera, not a cell",
                path=source,
                hint="leave out --camera for a one-camera result",
            )
        return res
    names = res.camera_names
    if camera is None and len(names) == 1:
        camera = names[0]
    if camera is None or camera not in names:
        what = "is a cell" if camera is None else f"has no camera {camera!r}"
        raise InputError(
            f"the result {what} of {len(names)} cameras ({', '.join(names)})",
            path=source,
            hint="choose one with --camera NAME",
        )
    return res.camera_result(camera)


def write_validated(path: Union[str, Path], d: dict, model: type[BaseModel], *, durable: bool = True) -> Path:
    """Validate ``d`` as ``model`` then write it atomically.

    A dict the model refuses is a bug of the
    writer: ValueError (exit 1), and the file is not written.
    """
    from ..output import atomic_write_text, to_json

    text = to_json(d)  # encoded once: checked as a reader will see it (through its JSON), then written
    check_written(json.loads(text), model, str(path))
    return atomic_write_text(path, text + "\n", durable=durable)


def check_written(d: dict, model: type[BaseModel], path: str) -> None:
    """Check that ``d`` (what handeye is about to write to ``path``, as its JSON reads back) fits ``model``.

    ValueError (a bug of the writer, exit 1) otherwise.
    """
    try:
        model.model_validate(d)
    except ValidationError as e:
        raise ValueError(f"handeye produced an invalid {Path(path).name}: {_error(e, path, 'file')}") from None


def write_result(path: Union[str, Path], d: dict, *, durable: bool = True) -> Path:
    """THE writer of result.json: validated (:class:`Result`), then written atomically."""
    return write_validated(path, d, Result, durable=durable)


def schema(model: type[BaseModel], file_name: str) -> dict:
    """The JSON schema (draft 2020-12) of ``model``, as published in ``docs/<file_name>``."""
    s = model.model_json_schema()
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        **s,
    }


def schema_texts() -> dict[str, str]:
    """Schema file name -> its text (sorted keys, 2-space indent, final newline)."""
    return {
        file_name: json.dumps(schema(model, file_name), indent=2, sort_keys=True) + "\n"
        for model, file_name in SCHEMAS.values()
    }
