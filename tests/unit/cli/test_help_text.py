"""``--help`` is plain text (the command modules' docstrings are reStructuredText), and every option of
``analyze`` and ``submit`` says what it is, with its unit where it has one."""

from __future__ import annotations

import argparse
import re
import subprocess
import sys

import pytest

from eigenscope._help import plain_text
from eigenscope.cli import build_parser

#: Sphinx roles, ``literals``, `default-role text`.
MARKUP = re.compile(r":[a-z]+:`|``|`[^`\s]")
#: The unit each numeric option of analyze and submit states.
UNITS = {
    "--force-n": "N",
    "--impulse-ns": "N·s",
    "--fps": "frames per second",
    "--fx": "pixels",
    "--fy": "pixels",
    "--cx": "pixels",
    "--cy": "pixels",
    "--depth-scale": "m",
    "--depth-m": "m",
    "--min-frequency-hz": "Hz",
    "--max-frequency-hz": "Hz",
    "--frames": "frames",
    "--point": "pixels",
    "--box": "pixels",
    "--timeout": "seconds",
    "--force-log-offset-s": "seconds",
}


def _subcommands() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    (sub,) = (a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


def _help(*argv: str) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "eigenscope", *argv, "--help"], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_plain_text_drops_roles_and_backticks() -> None:
    text = ":func:`~workers.runner.run_analysis` writes ``result.json``; see :mod:`service.app` and `--out`"
    assert plain_text(text) == "run_analysis writes result.json; see service.app and --out"
    assert plain_text("a ``literal`` and 2 * 3") == "a literal and 2 * 3"


@pytest.mark.parametrize("command", ["", "analyze", "submit", "stream", "probe", "serve", "worker"])
def test_help_has_no_restructured_text(command: str) -> None:
    text = _help(*([command] if command else []))
    assert not MARKUP.search(text), MARKUP.search(text)


def test_no_subcommand_help_has_markup_in_the_parser() -> None:
    for name, parser in _subcommands().items():
        assert not MARKUP.search(parser.format_help()), name


@pytest.mark.parametrize("command", ["analyze", "submit"])
def test_every_option_has_help_with_its_unit(command: str) -> None:
    parser = _subcommands()[command]
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        name = action.option_strings[-1] if action.option_strings else action.dest
        assert action.help, f"{command} {name} has no help"
        assert action.help is not argparse.SUPPRESS, f"{command} {name} hides its help"
        assert len(action.help) > 10, (command, name, action.help)
        unit = UNITS.get(name)
        if unit is not None:
            assert re.search(rf"(^|[\s(,]){re.escape(unit)}($|[\s),])", action.help), (
                command,
                name,
                action.help,
            )


def test_the_exit_statuses_are_documented() -> None:
    from eigenscope.cli import EXIT_BROKEN_PIPE

    text = " ".join(_help().split())
    assert f"{EXIT_BROKEN_PIPE} standard output was closed by its reader" in text
