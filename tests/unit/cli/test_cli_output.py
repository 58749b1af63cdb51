"""What ``eigenscope analyze`` leaves behind: a reader that stops reading ends the command quietly (exit 141),
a failed run leaves no folder it made, and ``result.json`` has the images' permissions, as the umask asks."""

from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from eigenscope.cli import EXIT_BROKEN_PIPE


def _closed_stdout(*args: object, umask: int | None = None) -> tuple[int, str]:
    """Run ``eigenscope ARGS`` writing into a real pipe whose reader has already gone."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "eigenscope", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=(lambda: os.umask(umask)) if umask is not None else None,
    )
    assert proc.stdout is not None
    assert proc.stderr is not None
    proc.stdout.close()
    err = proc.stderr.read().decode()
    proc.stderr.close()
    return proc.wait(timeout=600), err


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("pipe") / "clip.npz"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "eigenscope",
            "synth",
            "--out",
            str(out),
            "--frames",
            "48",
            "--width",
            "160",
            "--height",
            "120",
            "--seed",
            "5",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return out


def test_a_reader_that_stops_reading_is_no_internal_error() -> None:
    """``eigenscope export-openapi --out - | head -c 10``: the spec is far more than the reader takes."""
    code, err = _closed_stdout("export-openapi", "--out", "-")
    assert code == EXIT_BROKEN_PIPE == 141
    assert err == ""


def test_analyze_json_into_a_closed_pipe_keeps_its_files_with_the_images_permissions(
    clip: Path, tmp_path: Path
) -> None:
    out = tmp_path / "out"
    code, err = _closed_stdout("analyze", clip, "--force-n", 10, "--out", out, "--json", umask=0o027)
    assert code == EXIT_BROKEN_PIPE, err
    assert "Traceback" not in err
    assert "internal error" not in err
    modes = {p.name: stat.S_IMODE(p.stat().st_mode) for p in out.iterdir()}
    assert "result.json" in modes, modes
    assert "mask.png" in modes, modes
    assert set(modes.values()) == {0o640}, {n: oct(m) for n, m in modes.items()}


def _analyze_a_bad_clip(tmp_path: Path, out: Path) -> subprocess.CompletedProcess[str]:
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a clip at all" * 100)
    return subprocess.run(
        [sys.executable, "-m", "eigenscope", "analyze", str(bad), "--force-n", "10", "--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )


def test_a_failed_run_leaves_no_folder_it_made(tmp_path: Path) -> None:
    done = _analyze_a_bad_clip(tmp_path, tmp_path / "new" / "out")
    assert done.returncode == 2, done.stderr
    assert len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not (tmp_path / "new").exists()


def test_a_failed_run_keeps_a_folder_that_was_there(tmp_path: Path) -> None:
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    done = _analyze_a_bad_clip(tmp_path, out)
    assert done.returncode == 2, done.stderr
    assert (out / "notes.txt").read_text() == "the user's"


@pytest.mark.parametrize(
    ("kind", "release_time_s", "expected"),
    [
        ("step_release", 0.8, "held force 6 ± 0.01 N, released at 0.8000 s, from topic /ft"),
        ("impulse", 0.8, "impulse 6 ± 0.01 N·s, struck at 0.8000 s, from topic /ft"),
        ("forced", None, "a force that kept acting, RMS 6 ± 0.01 N, from topic /ft"),
    ],
)
def test_the_summary_names_each_kind_of_recorded_excitation(
    kind: str, release_time_s: float | None, expected: str
) -> None:
    from api_schemas import ExcitationUsed
    from eigenscope.commands.analyze import _excitation_text

    used = ExcitationUsed(
        type=kind,  # type: ignore[arg-type]
        value=6.0,
        uncertainty=0.01,
        release_time_s=release_time_s,
        source="topic /ft",
    )
    assert _excitation_text(used) == expected
