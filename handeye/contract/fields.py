"""The checked value types of handeye's files: numbers, matrices, covariances, image sizes.

Each type is a pydantic ``Annotated`` type with its own validator and JSON schema. A value that does
not fit raises a :class:`pydantic_core.PydanticCustomError` of type ``damaged`` whose context holds
``problem`` (what is wrong, e.g. ``is 'abc'``) and ``expected``: :mod:`handeye.contract` turns the first
one into a one-line :class:`~handeye.errors.InputError` naming the field path. Numbers are strict:
a string, a boolean or a list in a number's slot is refused, never converted.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Optional

import numpy as np
from pydantic import PlainValidator, WithJsonSchema
from pydantic_core import PydanticCustomError

from ..frames import is_rigid_transform


def damaged(problem: str, expected: str, field: Optional[str] = None) -> PydanticCustomError:
    """The error every check raises.

    ``problem`` (``is 'abc'``), ``expected`` and, from a whole-model check, the ``field`` it concerns.
    """
    ctx = {"problem": problem, "expected": expected}
    if field is not None:
        ctx["field"] = field
    return PydanticCustomError("damaged", "{problem}", ctx)


def short(v: Any, n: int = 60) -> str:
    """A value as a person reads it in one line, cut to ``n`` characters."""
    try:
        text = repr(v)
    except (RecursionError, ValueError):
        text = f"<{type(v).__name__}>"
    text = " ".join(text.split())
    return text if len(text) <= n else text[: n - 3] + "..."


def _number(v: Any, expected: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise damaged(f"is {short(v)}", expected)
    try:
        return float(v)
    except OverflowError:
        raise damaged("is a number too large for a float", expected) from None


def _finite(v: Any) -> float:
    f = _number(v, "a finite number")
    if not math.isfinite(f):
        raise damaged(f"is {short(f)}", "a finite number")
    return f


def _positive(v: Any) -> float:
    f = _number(v, "a finite number > 0")
    if not (math.isfinite(f) and f > 0):
        raise damaged(f"is {short(f)}", "a finite number > 0")
    return f


def _sigma(v: Any) -> float:
    """A standard deviation: a number not below 0 (NaN stands for "not estimated", as the writers store it)."""
    f = _number(v, "a number >= 0")
    if f < 0 or f == math.inf:
        raise damaged(f"is {short(f)}", "a number >= 0")
    return f


def _number_any(v: Any) -> float:
    return _number(v, "a number")


def _count(v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise damaged(f"is {short(v)}", "an integer >= 0")
    return v


def _rows(v: Any, shape: tuple, expected: str) -> np.ndarray:
    """A nested list of numbers of ``shape`` as an array; damaged otherwise (no strings, no booleans)."""
    if not isinstance(v, list):
        raise damaged(f"is {short(v)}", expected)

    def numbers(x, depth):
        if depth == len(shape):
            return not isinstance(x, bool) and isinstance(x, (int, float))
        return isinstance(x, list) and len(x) == shape[depth] and all(numbers(y, depth + 1) for y in x)

    if not numbers(v, 0):
        raise damaged(f"is {short(v)}", expected)
    try:
        return np.asarray(v, dtype=float)
    except OverflowError:
        raise damaged("holds a number too large for a float", expected) from None


def _rigid(v: Any) -> list:
    expected = "a finite 4x4 rigid transform (rotation block, last row 0 0 0 1)"
    _rows(v, (4, 4), expected)
    if not is_rigid_transform(v):
        raise damaged("is not a finite 4x4 rigid transform", expected)
    return v


def _matrix4(v: Any) -> list:
    a = _rows(v, (4, 4), "a 4x4 matrix of finite numbers")
    if not np.all(np.isfinite(a)):
        raise damaged("is not a finite 4x4 matrix", "a 4x4 matrix of finite numbers")
    return v


def _finite_numbers(v: Any, n: int) -> bool:
    """Whether ``v`` is a list of ``n`` finite floats or ints (exact types, as JSON gives them): the common case.

    The fast path of :func:`_vector`: observations.json holds tens of thousands of corner points, each checked.
    """
    return type(v) is list and len(v) == n and all(_plain_number(x) and math.isfinite(x) for x in v)


_FLOAT_MAX = 1.7976931348623157e308


def _plain_number(x: Any) -> bool:
    """A float, or an int a float holds (exact types, as JSON gives them; not a bool)."""
    t = type(x)
    return t is float or (t is int and -_FLOAT_MAX <= x <= _FLOAT_MAX)


def _number_rows(v: Any) -> list:
    """A list of lists of numbers (NaN and infinities allowed), e.g. a view's corner residuals.

    One pass over plain JSON values for the common case (observations.json holds tens of thousands); anything
    else is checked number by number, with the message of the first that is not one.
    """
    if type(v) is list and all(type(r) is list and all(_plain_number(x) for x in r) for r in v):
        return v
    expected = "a list of lists of numbers"
    if not isinstance(v, list):
        raise damaged(f"is {short(v)}", expected)
    for r in v:
        if not isinstance(r, list):
            raise damaged(f"holds {short(r)}", expected)
        for x in r:
            _number(x, expected)
    return v


def _vector(n: int):
    expected = f"{n} finite numbers"

    def check(v: Any) -> list:
        if _finite_numbers(v, n):
            return v
        a = _rows(v, (n,), expected)  # anything else: the general check, with its message
        if not np.all(np.isfinite(a)):
            raise damaged(f"is {short(v)}", expected)
        return v

    return check


def covariance_problem(a: np.ndarray) -> Optional[str]:
    """Why the square array ``a`` is not a covariance (finite, symmetric, positive definite), or None."""
    if not np.all(np.isfinite(a)):
        return "is not finite"
    scale = float(np.abs(a).max()) if a.size else 0.0
    if scale == 0.0:
        return "is all zeros"
    if not np.allclose(a, a.T, rtol=1e-6, atol=1e-12 * scale):
        return "is not symmetric"
    try:
        np.linalg.cholesky(0.5 * (a + a.T))
    except np.linalg.LinAlgError:
        return "is not positive definite"
    return None


def _covariance(n: Optional[int]):
    expected = f"a finite symmetric positive definite {n}x{n} covariance" if n else "a covariance matrix"

    def check(v: Any) -> list:
        k = len(v) if isinstance(v, list) else 0
        a = _rows(v, (n or k, n or k), expected)
        if a.size == 0:
            raise damaged("is empty", expected)
        why = covariance_problem(a)
        if why is not None:
            raise damaged(
                f"is not a finite symmetric positive definite covariance ({why.removeprefix('is ')})", expected
            )
        return v

    return check


def _matrix_any(v: Any) -> list:
    """A rectangular matrix of finite numbers (its shape is checked by the model that holds it)."""
    expected = "a matrix of finite numbers"
    if not (isinstance(v, list) and v and isinstance(v[0], list)):
        raise damaged(f"is {short(v)}", expected)
    a = _rows(v, (len(v), len(v[0])), expected)
    if not np.all(np.isfinite(a)):
        raise damaged("is not finite", expected)
    return v


def _image_size(v: Any) -> list:
    expected = "[width, height]: two integers > 0"
    if not (
        isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in v)
    ):
        raise damaged(f"is {short(v)}", expected)
    return v


def _view_id(v: Any):
    if isinstance(v, bool) or not isinstance(v, (str, int)):
        raise damaged(f"is {short(v)}", "a view id (a text or an integer)")
    return v


_NUM = {"type": "number"}


def _array(item: dict, n: Optional[int] = None) -> dict:
    d: dict = {"type": "array", "items": item}
    if n is not None:
        d.update(minItems=n, maxItems=n)
    return d


Finite = Annotated[float, PlainValidator(_finite), WithJsonSchema(_NUM)]
Positive = Annotated[float, PlainValidator(_positive), WithJsonSchema({"type": "number", "exclusiveMinimum": 0})]
Sigma = Annotated[float, PlainValidator(_sigma), WithJsonSchema({"type": "number", "minimum": 0})]
Number = Annotated[float, PlainValidator(_number_any), WithJsonSchema(_NUM)]
NumberRows = Annotated[list, PlainValidator(_number_rows), WithJsonSchema(_array(_array(_NUM)))]
Count = Annotated[int, PlainValidator(_count), WithJsonSchema({"type": "integer", "minimum": 0})]
Rigid = Annotated[
    list,
    PlainValidator(_rigid),
    WithJsonSchema(dict(_array(_array(_NUM, 4), 4), description="4x4 rigid transform T_a_b (p_a = T_a_b @ p_b)")),
]
Matrix4 = Annotated[list, PlainValidator(_matrix4), WithJsonSchema(_array(_array(_NUM, 4), 4))]
Vec2 = Annotated[list, PlainValidator(_vector(2)), WithJsonSchema(_array(_NUM, 2))]
Vec3 = Annotated[list, PlainValidator(_vector(3)), WithJsonSchema(_array(_NUM, 3))]
Vec4 = Annotated[list, PlainValidator(_vector(4)), WithJsonSchema(_array(_NUM, 4))]
Cov6 = Annotated[
    list,
    PlainValidator(_covariance(6)),
    WithJsonSchema(
        dict(_array(_array(_NUM, 6), 6), description="6x6 covariance: finite, symmetric, positive definite")
    ),
]
Covariance = Annotated[
    list,
    PlainValidator(_covariance(None)),
    WithJsonSchema(dict(_array(_array(_NUM)), description="square covariance: finite, symmetric, positive definite")),
]
Matrix = Annotated[list, PlainValidator(_matrix_any), WithJsonSchema(_array(_array(_NUM)))]
ImageSize = Annotated[
    list,
    PlainValidator(_image_size),
    WithJsonSchema(dict(_array({"type": "integer", "exclusiveMinimum": 0}, 2), description="[width, height] in px")),
]
ViewId = Annotated[Any, PlainValidator(_view_id), WithJsonSchema({"type": ["string", "integer"]})]
