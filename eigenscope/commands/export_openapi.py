"""``eigenscope export-openapi``: write the API's OpenAPI document (``openapi/openapi.json``) and the live
streams' AsyncAPI document beside it (``openapi/asyncapi.json``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

DEFAULT_PATH = Path("openapi/openapi.json")
#: The AsyncAPI document is written beside the OpenAPI one, under this name.
ASYNCAPI_NAME = "asyncapi.json"


def register(subparsers: Any) -> None:
    parser: argparse.ArgumentParser = subparsers.add_parser(
        "export-openapi", help="write the HTTP API's OpenAPI document", description=__doc__
    )
    parser.add_argument(
        "--out", type=Path, default=DEFAULT_PATH, help=f"destination (default {DEFAULT_PATH}; - for stdout)"
    )
    parser.add_argument(
        "--check", action="store_true", help="do not write; exit 1 if the file differs from the app's spec"
    )
    parser.set_defaults(handler=run)


def render_spec() -> str:
    """The app's OpenAPI document as the exact text kept in ``openapi/openapi.json``."""
    from backend.settings import Settings
    from service.app import create_app

    app = create_app(Settings(data_dir=Path("/nonexistent/eigenscope-openapi-export")))
    return json.dumps(app.openapi(), indent=2, ensure_ascii=False) + "\n"


def render_asyncapi() -> str:
    """The live streams' AsyncAPI document as the exact text kept in ``openapi/asyncapi.json``."""
    from service.app import API_VERSION
    from service.asyncapi import asyncapi_document

    return json.dumps(asyncapi_document(version=API_VERSION), indent=2, ensure_ascii=False) + "\n"


def run(args: argparse.Namespace) -> int:
    text = render_spec()
    if str(args.out) == "-":
        sys.stdout.write(text)
        return 0
    out: Path = args.out
    documents = {out: text, out.with_name(ASYNCAPI_NAME): render_asyncapi()}
    if args.check:
        stale = [
            p for p, t in documents.items() if (p.read_text(encoding="utf-8") if p.exists() else "") != t
        ]
        for path in stale:
            print(f"{path} is out of date; run `eigenscope export-openapi`", file=sys.stderr)
        if stale:
            return 1
        print(f"{', '.join(map(str, documents))} up to date", file=sys.stderr)
        return 0
    out.parent.mkdir(parents=True, exist_ok=True)
    for path, content in documents.items():
        path.write_text(content, encoding="utf-8")
        print(f"wrote {path}", file=sys.stderr)
    return 0
