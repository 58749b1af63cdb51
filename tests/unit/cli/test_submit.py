"""``eigenscope submit --force-log FILE [--force-log-offset-s S]``: the log goes into the job request (its
times as recorded, the offset as its ``offset_s``), a file that is not a log is one line and exit status 2
before anything is sent, and the command still loads neither numpy nor OpenCV."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from eigenscope.cli import build_parser
from eigenscope.commands.submit import job_request

LOG = "# frame_id: ft_sensor_link\ntime_s,fx,fy,fz\n" + "".join(
    f"{i / 500:.3f},{6.0 if i < 10 else 0.0},0.1,-0.2\n" for i in range(20)
)
#: A server nobody listens on: the command must stop before it would connect.
NOWHERE = "http://127.0.0.1:9"


@pytest.fixture
def clip(tmp_path: Path) -> Path:
    path = tmp_path / "push.mp4"
    path.write_bytes(b"not read: the command stops before the upload")
    return path


def test_the_log_goes_into_the_request(tmp_path: Path, clip: Path) -> None:
    log = tmp_path / "push.csv"
    log.write_text(LOG)
    args = build_parser().parse_args(
        ["submit", str(clip), "--server", NOWHERE, "--force-log", str(log), "--force-log-offset-s", "-12.5"]
    )
    request = job_request(args)
    sent = request["force_log"]
    assert request["excitation"] is None
    assert sent.name == "push.csv"
    assert sent.frame_id == "ft_sensor_link"
    assert sent.offset_s == -12.5
    assert sent.time_s[:2] == (0.0, 0.002)
    assert sent.to_dict()["fx"][9:11] == [6.0, 0.0]
    # Without the option there is none; a typed force still goes as before.
    plain = build_parser().parse_args(["submit", str(clip), "--server", NOWHERE, "--force-n", "5"])
    assert job_request(plain)["force_log"] is None
    assert job_request(plain)["excitation"].force_n == 5


@pytest.mark.parametrize(
    ("content", "options", "words"),
    [
        (LOG.replace("0.004,", "0.001,"), [], "time_s[2] = 0.001 s runs backwards"),
        ("time_s,torque\n0,1\n", [], "lacks the columns it needs"),
        (LOG.replace("0.1,-0.2\n", "nan,-0.2\n", 1), [], "fy[0] is nan"),
        (None, [], "no such file"),
        (LOG, ["--force-log-offset-s", "nan"], "offset_s is nan"),
    ],
    ids=["backwards", "not-a-log", "not-finite", "missing", "offset-not-finite"],
)
def test_a_bad_log_is_one_line_and_status_2(
    run_eigenscope: Callable[..., subprocess.CompletedProcess[str]],
    tmp_path: Path,
    clip: Path,
    content: str | None,
    options: list[str],
    words: str,
) -> None:
    log = tmp_path / "push.csv"
    if content is not None:
        log.write_text(content)
    done = run_eigenscope("submit", clip, "--server", NOWHERE, "--force-log", log, *options)
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("eigenscope submit: error: --force-log")
    assert words in lines[0]
    assert "Traceback" not in done.stderr
    assert "127.0.0.1:9" not in done.stderr  # refused before any connection


def test_an_offset_needs_a_log(
    run_eigenscope: Callable[..., subprocess.CompletedProcess[str]], clip: Path
) -> None:
    done = run_eigenscope("submit", clip, "--server", NOWHERE, "--force-log-offset-s", "2")
    assert done.returncode == 2
    assert done.stderr.strip() == (
        "eigenscope submit: error: --force-log-offset-s needs --force-log FILE: it shifts that log's times"
    )


def test_submit_with_a_log_loads_neither_numpy_nor_opencv(tmp_path: Path, clip: Path) -> None:
    log = tmp_path / "push.csv"
    log.write_text(LOG)
    code = (
        "import sys; from eigenscope.cli import main; "
        f"status = main(['submit', {str(clip)!r}, '--server', {NOWHERE!r}, '--force-log', {str(log)!r}]); "
        "print(status, sorted(m for m in ('numpy', 'cv2', 'workers', 'av') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    # The log was read, then the upload found no server: status 2 with one line naming the server.
    assert done.stdout.split() == ["2", "[]"], done
    assert "127.0.0.1:9" in done.stderr
