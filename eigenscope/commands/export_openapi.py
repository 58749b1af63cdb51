"""``eigenscope export-openapi``: write the API's OpenAPI document (``openapi/openapi.json``)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

DEFAULT_PATH = Path("openapi/openapi.json")


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
    from service.app import create_app
    from service.settings import Settings

    app = create_app(Settings(data_dir=Path("/nonexistent/eigenscope-openapi-export")))
    return json.dumps(app.openapi(), indent=2, ensure_ascii=False) + "\n"


def run(args: argparse.Namespace) -> int:
    text = render_spec()
    if str(args.out) == "-":
        sys.stdout.write(text)
        return 0
    out: Path = args.out
    if args.check:
        current = out.read_text(encoding="utf-8") if out.exists() else ""
        if current != text:
            print(f"{out} is out of date; run `eigenscope export-openapi`", file=sys.stderr)
            return 1
        print(f"{out} is up to date", file=sys.stderr)
        return 0
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    print(f"wrote {out}", file=sys.stderr)
    return 0
