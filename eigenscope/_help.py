"""Plain text for ``--help``: the command modules' docstrings are reStructuredText, a terminal is not."""

from __future__ import annotations

import argparse
import re

#: ``:func:`x```, ``:mod:`~a.b```, ``:ref:`title <target>```: a Sphinx role around its target.
_ROLE = re.compile(r":[a-z]+(?::[a-z]+)?:`~?([^`<]*?)(?:\s*<[^`>]*>)?`")
#: ````literal```` and ```default role```.
_LITERAL = re.compile(r"``(.+?)``|`([^`\s][^`]*?)`")


def plain_text(text: str) -> str:
    """``text`` without reStructuredText markup: roles, double and single backticks.

    ``:func:`~workers.runner.run_analysis``` becomes ``run_analysis``, ````--out DIR```` becomes
    ``--out DIR``.
    """

    def role(match: re.Match[str]) -> str:
        target = match.group(1).strip()
        return target.rsplit(".", 1)[-1] if match.group(0).split("`", 1)[1].startswith("~") else target

    text = _ROLE.sub(role, text)
    return _LITERAL.sub(lambda m: m.group(1) or m.group(2), text)


def clean_help(parser: argparse.ArgumentParser) -> None:
    """Make the description, epilog and every option's help of ``parser`` and its subcommands plain text."""
    for attr in ("description", "epilog"):
        value = getattr(parser, attr)
        if value:
            setattr(parser, attr, plain_text(value))
    for action in parser._actions:
        if action.help and action.help is not argparse.SUPPRESS:
            action.help = plain_text(action.help)
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                if choice.help:
                    choice.help = plain_text(choice.help)
            for sub in dict.fromkeys(action.choices.values()):
                clean_help(sub)
