"""JSON parsed within limits: finite numbers and a bounded depth.

The API's request bodies (:mod:`service.bodies`) are refused when they hold ``NaN``, ``Infinity`` or a
number that overflows (:func:`strict_json_loads`); the stream messages that the API's relay and a
stream's worker read are refused when nested too deep (:func:`loads_shallow`), with a ``ValueError``
rather than a ``RecursionError``.
"""

from __future__ import annotations

import json
import math
from typing import Any

_INT64 = 2**63


class NonFiniteNumberError(ValueError):
    """A JSON number that is not a finite float or a 64-bit integer."""


def _constant(name: str) -> Any:
    raise NonFiniteNumberError(f"{name} is not a number JSON can carry; send finite numbers")


def _float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise NonFiniteNumberError(f"{text} overflows a 64-bit float; send finite numbers")
    return value


def _int(text: str) -> int:
    value = int(text)
    if not -_INT64 <= value < _INT64:
        raise NonFiniteNumberError(f"{text[:40]} overflows a 64-bit integer")
    return value


def strict_json_loads(body: bytes | str) -> Any:
    """``json.loads`` that refuses ``NaN``, ``Infinity``, overflowing floats and integers beyond 64 bits.

    Raises
    ------
    NonFiniteNumberError
        For such a number (other malformed JSON raises what ``json.loads`` raises).
    """
    return json.loads(body, parse_constant=_constant, parse_float=_float, parse_int=_int)


def non_finite_path(value: Any) -> list[str | int] | None:
    """Where in parsed JSON (``json.loads``, which lets them through) the first number is that
    :func:`strict_json_loads` refuses: the keys and list indices down to it, or None when there is none."""
    stack: list[tuple[Any, list[str | int]]] = [(value, [])]
    while stack:
        item, path = stack.pop()
        if isinstance(item, float) and not math.isfinite(item):
            return path
        if isinstance(item, int) and not isinstance(item, bool) and not -_INT64 <= item < _INT64:
            return path
        if isinstance(item, dict):
            stack.extend((v, [*path, str(k)]) for k, v in reversed(list(item.items())))
        elif isinstance(item, list):
            stack.extend((v, [*path, i]) for i, v in reversed(list(enumerate(item))))
    return None


def json_depth_error(text: str, max_depth: int) -> str | None:
    """Why ``text`` must not be parsed: nested deeper than ``max_depth`` arrays and objects (a parser
    would recurse that deep); None when it may be. Brackets inside strings do not count."""
    depth = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            if depth > max_depth:
                return f"JSON nested more than {max_depth} levels deep"
        elif char in "]}":
            depth -= 1
    return None


def loads_shallow(data: bytes | str, *, max_depth: int) -> Any:
    """``json.loads`` of a message that must be shallow: ``ValueError`` (never ``RecursionError``) for one
    nested deeper than ``max_depth``, or otherwise malformed."""
    text = data.decode("utf-8") if isinstance(data, bytes) else data  # UnicodeDecodeError is a ValueError
    why = json_depth_error(text, max_depth)
    if why is not None:
        raise ValueError(why)
    try:
        return json.loads(text)
    except RecursionError:  # pragma: no cover - the depth was checked
        raise ValueError("JSON nested too deep") from None
