"""``eigenscope analyze`` from the outside, given bad input: a real process, one line on stderr, exit status
2 (its analyses are in ``tests/accuracy/cli/test_analyze_cli.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from workers.pipeline.clipio import write_npz


@pytest.mark.parametrize(
    ("make", "args", "expected"),
    [
        ("missing", [], "No such file"),
        ("text", [], "not a"),
        ("few-frames", [], "frames"),
        ("no-rgb", [], "missing key 'rgb'"),
        ("ok", ["--fps", "-3"], "--fps"),
        ("ok", ["--force-n", "10", "--point", "1", "1"], "matches no object"),
        ("ok", ["--frames", "4"], "frames"),
        ("ok", ["--flow-threads", "0"], "--flow-threads"),
    ],
)
def test_bad_input_gets_one_line_and_exit_2(make, args, expected, cli_clip, run_eigenscope, tmp_path):
    path = tmp_path / "bad.npz"
    if make == "text":
        path.write_text("not a clip\n")
    elif make == "few-frames":
        write_npz(path, np.zeros((3, 32, 32, 3), np.uint8), fps=30)
    elif make == "no-rgb":
        np.savez(path, colour=np.zeros((10, 32, 32, 3), np.uint8), fps=30.0)
    elif make == "ok":
        path = cli_clip
    done = run_eigenscope("analyze", path, *args, "--out", tmp_path / "out")
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert expected.lower() in lines[0].lower()


@pytest.mark.parametrize(
    ("rows", "options", "expected"),
    [
        (200_001, [], "time_s: list should have at most 200000 items"),
        (400, [], "another clock; give its offset (--force-log-offset-s"),
    ],
    ids=["too-long", "another-clock"],
)
def test_a_force_log_that_cannot_be_used_gets_one_line_and_exit_2(
    rows, options, expected, cli_clip, run_eigenscope, tmp_path
):
    """A log longer than a request may carry, or kept on another clock with no offset given."""
    log = tmp_path / "push.csv"
    times = 1234.4 + np.arange(rows) / 500  # the robot's clock
    force = np.where(np.arange(rows) < rows // 2, 6.0, 0.0)
    log.write_text(
        "time_s,force_n\n"
        + "".join(f"{t!r},{f!r}\n" for t, f in zip(times.tolist(), force.tolist(), strict=True))
    )
    done = run_eigenscope("analyze", cli_clip, "--force-log", log, *options, "--out", tmp_path / "out")
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert expected.lower() in lines[0].lower()
