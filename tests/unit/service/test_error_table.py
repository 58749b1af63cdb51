"""One table maps error codes to HTTP status and title (``backend.errors.PROBLEM_TYPES``): every code the
service, the back end or the workers report is in it, nothing else assigns a status or a title, and the
OpenAPI document lists exactly the table."""

from __future__ import annotations

import ast
import json
from pathlib import Path

import pytest

from backend.errors import (
    PROBLEM_BASE,
    PROBLEM_TYPES,
    InvalidClipError,
    PayloadTooLargeError,
    ServiceError,
    problem_document,
)
from service.openapi import problem_types_extension

ROOT = Path(__file__).resolve().parents[3]
SOURCES = sorted(
    path for package in ("backend", "service", "workers") for path in (ROOT / package).rglob("*.py")
)
#: Functions, and methods called on ``self``, whose first argument is an error code.
CODE_FUNCTIONS = {"problem_document", "problem_type", "_head"}
CODE_METHODS = {"error", "fatal"}


def _codes_in(tree: ast.AST) -> set[str]:
    """Error codes written in ``tree``: ``code=`` arguments and defaults, ``"code": ...`` members,
    ``code = ...`` class attributes, and the first argument of the problem builders."""

    def text(node: ast.AST | None) -> str | None:
        return node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else None

    found: set[str | None] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            found |= {text(k.value) for k in node.keywords if k.arg == "code"}
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            on_self = isinstance(func, ast.Attribute) and getattr(func.value, "id", "") == "self"
            if node.args and (name in CODE_FUNCTIONS or (name in CODE_METHODS and on_self)):
                found.add(text(node.args[0]))
        elif isinstance(node, ast.Dict):
            found |= {text(v) for k, v in zip(node.keys, node.values, strict=True) if text(k) == "code"}
        elif isinstance(node, ast.ClassDef):
            for stmt in node.body:
                targets = stmt.targets if isinstance(stmt, ast.Assign) else []
                if isinstance(stmt, ast.AnnAssign):
                    targets = [stmt.target]
                if any(isinstance(t, ast.Name) and t.id == "code" for t in targets):
                    found.add(text(stmt.value))
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            args = node.args
            named = [*args.posonlyargs, *args.args]
            defaults = dict(
                zip([a.arg for a in named][len(named) - len(args.defaults) :], args.defaults, strict=True)
            )
            defaults |= {
                a.arg: d for a, d in zip(args.kwonlyargs, args.kw_defaults, strict=True) if d is not None
            }
            found.add(text(defaults.get("code")))
    return {c for c in found if c is not None}


def _used_codes() -> dict[str, str]:
    used: dict[str, str] = {}
    for path in SOURCES:
        for code in _codes_in(ast.parse(path.read_text(encoding="utf-8"))):
            used.setdefault(code, str(path.relative_to(ROOT)))
    return used


def test_the_scan_finds_codes_however_they_are_written() -> None:
    tree = ast.parse(
        "class E(Exception):\n    code = 'a'\n"
        "def f(detail, *, code='b'): ...\n"
        "raise X('d', code='c')\n"
        "emit({'code': 'd', 'detail': 'x'})\n"
        "problem_document('e', 'x')\n"
        "self.error('f', 'x')\n"
    )
    assert _codes_in(tree) == {"a", "b", "c", "d", "e", "f"}


def test_every_code_in_use_is_in_the_table() -> None:
    used = _used_codes()
    assert len(used) > 40, used
    missing = {code: where for code, where in used.items() if code not in PROBLEM_TYPES}
    assert not missing, f"add these codes to backend.errors.PROBLEM_TYPES: {missing}"


def test_the_table_has_no_dead_entries() -> None:
    used = _used_codes()
    dead = sorted(set(PROBLEM_TYPES) - set(used))
    assert not dead, f"no module reports these codes; remove them from PROBLEM_TYPES: {dead}"


def test_the_table_is_well_formed() -> None:
    for code, kind in PROBLEM_TYPES.items():
        assert code == code.lower(), code
        assert " " not in code, code
        assert 400 <= kind.status <= 599, (code, kind)
        assert kind.title[:1].isupper(), (code, kind)


def test_no_other_module_writes_a_problem_document_by_hand() -> None:
    """A dict literal with a literal ``title`` or ``status`` is a second table in the making."""
    offenders = []
    for path in SOURCES:
        if path.name == "errors.py" and path.parent.name == "backend":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Dict):
                members = {
                    k.value: v
                    for k, v in zip(node.keys, node.values, strict=True)
                    if isinstance(k, ast.Constant)
                }
                literal = [m for m in ("title", "status") if isinstance(members.get(m), ast.Constant)]
                if {"type", "title", "status"} <= members.keys() and literal:
                    offenders.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not offenders, f"take status and title from backend.errors.PROBLEM_TYPES: {offenders}"


@pytest.mark.parametrize("code", sorted(PROBLEM_TYPES))
def test_errors_and_documents_take_status_and_title_from_the_table(code: str) -> None:
    kind = PROBLEM_TYPES[code]
    error = ServiceError("the detail", code=code)
    assert (error.status, error.title, error.type_uri) == (kind.status, kind.title, PROBLEM_BASE + code)
    assert error.problem()["status"] == kind.status
    doc = problem_document(code, "the detail at /srv/data/jobs/x/clip.npz")
    assert doc == {
        "type": PROBLEM_BASE + code,
        "title": kind.title,
        "status": kind.status,
        "detail": "the detail at clip.npz",
        "code": code,
    }


def test_the_api_and_the_workers_agree_on_clip_too_large() -> None:
    """The disagreement that started the table: the API said "Payload too large", the workers "Clip too
    large"."""
    assert PayloadTooLargeError("x").title == problem_document("clip-too-large", "x")["title"]
    assert InvalidClipError("x").status == problem_document("invalid-clip", "x")["status"]


def test_a_code_missing_from_the_table_says_where_to_add_it() -> None:
    with pytest.raises(KeyError, match="PROBLEM_TYPES"):
        problem_document("no-such-code", "x")


def test_the_openapi_document_lists_exactly_the_table() -> None:
    spec = json.loads((ROOT / "openapi" / "openapi.json").read_text(encoding="utf-8"))
    listed = spec["components"]["schemas"]["Problem"]["x-problem-types"]
    assert listed == problem_types_extension()
    assert {uri.removeprefix(PROBLEM_BASE): (v["status"], v["title"]) for uri, v in listed.items()} == {
        code: tuple(kind) for code, kind in PROBLEM_TYPES.items()
    }
    # Every status a documented problem type has is declared by some operation, except those only a job's
    # or a stream's record carries (they are not HTTP responses of the API).
    declared = {int(s) for item in spec["paths"].values() for op in item.values() for s in op["responses"]}
    api = {
        "clip-too-large",
        "unsupported-format",
        "invalid-clip",
        "not-found",
        "conflict",
        "unauthorized",
    }
    for code in api:
        assert PROBLEM_TYPES[code].status in declared, code
