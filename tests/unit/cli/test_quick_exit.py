"""The one-shot command's exit without teardown (``eigenscope._exit.leave``) loses no output and keeps the
status; ``eigenscope analyze`` uses it."""

from __future__ import annotations

import subprocess
import sys


def test_leave_flushes_what_was_printed_and_keeps_the_status():
    code = (
        "import logging, sys\n"
        "logging.basicConfig(stream=sys.stderr, format='%(message)s')\n"
        "from eigenscope._exit import leave\n"
        "print('result line', end='')\n"
        "sys.stderr.write('note')\n"
        "logging.getLogger('x').warning(' logged')\n"
        "import atexit\n"
        "atexit.register(lambda: print('teardown ran'))\n"
        "leave(3)\n"
        "print('not reached')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=False
    )
    assert done.returncode == 3
    assert done.stdout == "result line"  # buffered output flushed; no atexit handler, nothing after leave
    assert done.stderr == "note logged\n"


def test_analyze_is_a_one_shot_command():
    from eigenscope.cli import _ONE_SHOT_COMMANDS

    assert "analyze" in _ONE_SHOT_COMMANDS
