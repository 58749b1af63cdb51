"""Request validation errors in the user's words.

Pydantic reports where a value failed in terms of its validators: a union's alternatives appear in the
location (``tagged-union[StepReleaseExcitation,ImpulseExcitation]``, ``list[...]``, ``function-after[...]``)
and each alternative that did not match adds an error of its own ("Input should be a valid list" for a
single excitation). :func:`field_errors` turns them into what the request's author wrote and what to
send instead: the location as the fields they sent (``body.excitation.force_n``), one error per field,
from the alternative that fitted the input's shape, and messages that name the field.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

#: A location part that names a validator of a union's alternative, not a field the user sent.
_VALIDATOR = re.compile(r"^[a-z][\w-]*\[.*\]$")
#: Errors saying the input has another shape than this alternative wants: the user meant another one.
_SHAPE_ERRORS = frozenset(
    {"list_type", "dict_type", "model_type", "model_attributes_type", "tuple_type", "is_instance_of"}
)
#: What each excitation type is, to say when one is missing or unknown.
EXCITATION_TYPES = {
    "step_release": "held by a known force, then released (give force_n, newtons)",
    "impulse": "struck by a known impulse (give impulse_ns, newton-seconds)",
}


#: What a required field is, for the message that says it is missing.
FIELD_HINTS = {
    "force_n": "the force that held the object before its release, newtons",
    "impulse_ns": "the impulse that struck the object, newton-seconds",
    "clip_id": "the id `POST /v1/clips` returned",
    "type": "the kind of excitation: 'step_release' or 'impulse'",
}


def _user_loc(loc: Sequence[Any], tags: Iterable[str]) -> tuple[list[str | int], str | None, bool]:
    """The location without validator names and union tags, the tag of the alternative it went down (if
    any), and whether a union's alternative was in it."""
    out: list[str | int] = []
    tag: str | None = None
    branch = skip_tag = False
    known = set(tags)
    for part in loc:
        if isinstance(part, str) and _VALIDATOR.match(part):
            branch = True
            skip_tag = "tagged-union" in part  # the alternative's tag follows (after a list index)
            continue
        if skip_tag and isinstance(part, str) and part in known:
            tag, skip_tag = part, False
            continue
        if not isinstance(part, int):
            skip_tag = False
        out.append(part if isinstance(part, int) else str(part))
    return out, tag, branch


def _dotted(loc: Sequence[str | int]) -> str:
    return ".".join(str(x) for x in loc)


def _message(err: Mapping[str, Any], loc: Sequence[str | int], tag: str | None) -> str:
    """What is wrong, for a user who knows where (``loc`` says it): no validator's vocabulary."""
    kind = str(err.get("type", ""))
    name = str(loc[-1]) if loc else "body"
    if kind == "missing":
        hint = FIELD_HINTS.get(name)
        owner = f"an excitation of type {tag!r}" if tag else (_dotted(loc[1:-1]) or "the request")
        return f"required: {owner} needs {hint or name}"
    if kind == "extra_forbidden":
        return f"not a field of {_dotted(loc[1:-1]) or 'the request'}: leave it out or check its spelling"
    if kind in ("union_tag_not_found", "union_tag_invalid"):
        given = (err.get("ctx") or {}).get("tag")
        choices = "; ".join(f"'{t}': {what}" for t, what in EXCITATION_TYPES.items())
        said = f", not '{given}'" if given is not None else ""
        return f"give the kind of excitation in `type`{said}: {choices}"
    if kind in _SHAPE_ERRORS and len(loc) <= 1:
        return "the body must be a JSON object"
    msg = str(err.get("msg", "")).rstrip(".")
    return f"{msg[:1].lower()}{msg[1:]}" if msg else "not valid"


#: Pydantic's errors read at most, and field errors a problem document lists at most: a force log of
#: 200,000 numbers that are all wrong would otherwise list each (and take quadratic time to merge).
MAX_READ_ERRORS = 1000
MAX_FIELD_ERRORS = 50


def summary(errors: Sequence[Mapping[str, Any]], *, limit: int = 5, truncated: bool = False) -> str:
    """The problem's ``detail`` for its field errors: ``where: what`` of the first few (``truncated``:
    there were more errors than ``errors`` holds)."""
    parts = []
    for e in errors[:limit]:
        where = _dotted([x for x in e["loc"] if x != "body"]) or "body"
        parts.append(f"{where}: {e['msg']}")
    more = len(errors) - limit
    if more > 0:
        return "; ".join(parts) + f" (and {'over ' if truncated else ''}{more} more)"
    return "; ".join(parts) + (" (and more)" if truncated else "")


def _covered(loc: Sequence[str | int], others: Iterable[tuple[list[str | int], bool, str]]) -> bool:
    """Whether an alternative got further at or below ``loc`` (an error that is not about shape)."""
    n = len(loc)
    return any(b and k not in _SHAPE_ERRORS and list(o[:n]) == list(loc) for o, b, k in others)


def field_errors(
    errors: Sequence[Mapping[str, Any]], *, tags: Iterable[str] = EXCITATION_TYPES
) -> list[dict[str, Any]]:
    """The ``errors`` of a problem document for pydantic's ``errors`` (see the module docstring): those of
    the first :data:`MAX_READ_ERRORS` of them."""
    cleaned = [(*_user_loc(err.get("loc", ()), tags), err) for err in errors[:MAX_READ_ERRORS]]
    summary = [(loc, branch, str(err.get("type", ""))) for loc, _tag, branch, err in cleaned]
    out: list[dict[str, Any]] = []
    listed: set[tuple[tuple[str | int, ...], str, str]] = set()
    shapes: dict[tuple[str | int, ...], dict[str, Any]] = {}
    for loc, tag, branch, err in cleaned:
        kind = str(err.get("type", ""))
        if branch and kind in _SHAPE_ERRORS:
            if _covered(loc, summary):
                continue  # the input had the shape of another alternative, which reported what is wrong
            merged = shapes.get(tuple(loc))
            if merged is not None:  # no alternative fits: one error naming what each wants
                merged["msg"] += f", or {str(err.get('msg', '')).rstrip('.').lower()}"
                continue
        msg = _message(err, loc, tag)
        item = {"loc": loc, "msg": msg, "type": kind}
        if branch and kind in _SHAPE_ERRORS:
            shapes[tuple(loc)] = item
        key = (tuple(loc), msg, kind)
        if key not in listed:
            listed.add(key)
            out.append(item)
    return out
