"""The ``eigenscope`` console script.

Each subcommand lives in its own module under :mod:`eigenscope.commands` and exposes
``register(subparsers)``; heavy imports (OpenCV, FastAPI, Celery) happen inside the command handlers, so
``eigenscope --help`` is fast and ``serve`` never loads the pipeline into the API process.

Errors the user can fix print one line to stderr and exit with status 2; no traceback reaches the user
unless ``EIGENSCOPE_DEBUG=1``. A reader that stops reading (``eigenscope analyze CLIP --json | head``) ends
the command quietly with status 141, as the shell reports a command killed by ``SIGPIPE`` (128 + 13): the
output was not all delivered, which is no internal error either.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from collections.abc import Callable, Sequence

from eigenscope import _heap
from eigenscope._help import clean_help

#: Modules under eigenscope.commands, in help order.
COMMAND_MODULES = (
    "analyze",
    "synth",
    "probe",
    "serve",
    "worker",
    "stream_worker",
    "submit",
    "stream",
    "export_openapi",
)

Handler = Callable[[argparse.Namespace], int]

#: Exit status when standard output's reader went away: 128 + SIGPIPE, as a shell reports it.
EXIT_BROKEN_PIPE = 141


class UsageError(Exception):
    """A mistake in the command line or its input that the user can fix; printed as one line."""


class _VersionAction(argparse.Action):
    """``--version``: prints ``eigenscope VERSION`` and exits, reading the version only then (its module's
    package loads pydantic, which most commands do not need at start)."""

    def __init__(
        self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, **kwargs: object
    ) -> None:
        super().__init__(
            option_strings, dest, nargs=0, default=argparse.SUPPRESS, help="show the version and exit"
        )

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        from backend.version import __version__

        print(f"eigenscope {__version__}")
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="eigenscope",
        description="Measure eigenfrequency, damping, stiffness and mass of objects from RGB-D clips.",
        epilog="Exit status: 0 done; 1 the job failed (submit) or a file is stale (export-openapi --check); "
        "2 bad input or usage (one line on "
        "stderr says what to fix); 70 internal error; 130 interrupted; 141 standard output was closed by "
        "its reader (e.g. | head).",
    )
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"eigenscope.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"eigenscope.commands.{name}":
                continue  # command not built yet in this tree
            raise
        module.register(sub)
    clean_help(parser)
    return parser


def _user_error_types() -> tuple[type[BaseException], ...]:
    types: list[type[BaseException]] = [UsageError, FileNotFoundError, IsADirectoryError, PermissionError]
    # Only look the domain errors up if the pipeline was loaded by the command: no import cost otherwise.
    errors = sys.modules.get("workers.pipeline.errors")
    if errors is not None:
        types.append(errors.EigenscopeError)
    return tuple(types)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    handler: Handler = args.handler
    try:
        code = handler(args)
        sys.stdout.flush()  # a reader that went away shows here, not at exit
        return code
    except BrokenPipeError:
        return _reader_gone()
    except KeyboardInterrupt:
        print("eigenscope: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if os.environ.get("EIGENSCOPE_DEBUG") == "1":
            raise
        if isinstance(exc, _user_error_types()):
            message = (
                str(exc)
                if not isinstance(exc, OSError) or not exc.filename
                else (f"{exc.filename}: {exc.strerror}")
            )
            print(f"eigenscope {args.command}: error: {message}", file=sys.stderr)
            return 2
        print(
            f"eigenscope {args.command}: internal error: {type(exc).__name__}: {exc} "
            "(set EIGENSCOPE_DEBUG=1 for the traceback and report it)",
            file=sys.stderr,
        )
        return 70


def _reader_gone() -> int:
    """Standard output's reader went away: drop what is still buffered for it, quietly."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # later flushes (at exit) write nowhere instead of failing
        os.close(devnull)
    except (OSError, ValueError):
        pass
    return EXIT_BROKEN_PIPE


def console_main() -> None:
    """The ``eigenscope`` executable: :func:`main`, then exit with its status (the heap settled first, so
    that the interpreter's teardown does not go over it: :mod:`eigenscope._heap`)."""
    _heap.for_this_process()
    code = main(sys.argv[1:])
    _heap.settle()
    raise SystemExit(code)
