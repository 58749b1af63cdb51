"""Coverage-guided fuzzing of every clip reader with atheris (libFuzzer for Python).

Each input is written to a file and opened with :func:`workers.pipeline.clipio.open_clip` (the format is
detected from the content, as for an upload), and the first frames are streamed. The invariant: only
domain errors (:class:`workers.pipeline.errors.EigenscopeError`) may escape, in bounded memory
(``-rss_limit_mb``) and time (``-timeout``); anything else is a finding, saved by libFuzzer as
``crash-<sha1>`` (or ``oom-``/``timeout-``) with its traceback.

Run it (the seeds are small valid clips of every format, from ``tests/fuzz/seeds.py``)::

    python tests/fuzz/seeds.py fuzz-seeds/
    mkdir -p fuzz-corpus
    python tests/fuzz/fuzz_clips.py fuzz-corpus/ fuzz-seeds/ \
        -max_total_time=3600 -rss_limit_mb=1536 -timeout=30

The test suite runs it for about a minute (``tests/fuzz/test_fuzz_readers.py``). Pure-Python code is
instrumented for coverage (the readers, ``zipfile``, numpy's ``.npy`` header parser, ``rosbags``);
FFmpeg (PyAV) and OpenCV are native and exercised without coverage feedback.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

# isort: off
import eigenscope  # noqa: F401 - one BLAS/OpenCV thread, as in every entry point

# isort: on
import atheris

with atheris.instrument_imports(
    include=["workers.pipeline.clipio", "zipfile", "numpy.lib.format", "rosbags"]
):
    import zipfile  # noqa: F401

    import numpy.lib.format  # noqa: F401
    import rosbags.rosbag1
    import rosbags.rosbag2
    import rosbags.typesys

    from workers.pipeline.clipio import ReadLimits, open_clip
    from workers.pipeline.errors import EigenscopeError

del rosbags

#: Tight caps: the fuzzer must hit them, not this machine's memory.
LIMITS = ReadLimits(
    max_frames=2_000,
    max_pixels_per_frame=1024 * 1024,
    max_uncompressed_bytes=64 * 1024 * 1024,
    max_entries=2_000,
    max_decoded_bytes=256 * 1024 * 1024,
    inflation_floor_bytes=4 * 1024 * 1024,
)
#: Frames streamed per input: enough to reach every frame path, few enough to keep runs fast.
FRAMES = 9

_SHM = Path("/dev/shm")
WORK = Path(tempfile.mkdtemp(prefix="eigenscope-fuzz-", dir=_SHM if _SHM.is_dir() else None))


def _suffix(data: bytes) -> str:
    """The extension an uploader would give the file (the readers take it as a hint only)."""
    if data.startswith(b"#ROSBAG"):
        return ".bag"
    if data.startswith(b"\x89MCAP"):
        return ".mcap"
    if data.startswith(b"SQLite format 3"):
        return ".db3"
    if data.startswith(b"PK"):
        return ".zip"
    return ".bin"


def read_clip(data: bytes) -> None:
    """One fuzz input: open it as a clip and stream its first frames; domain errors are expected."""
    path = WORK / f"clip{_suffix(data)}"
    path.write_bytes(data)
    scratch = WORK / "scratch"
    scratch.mkdir(exist_ok=True)
    try:
        with open_clip(path, limits=LIMITS, scratch_dir=scratch) as reader:
            info = reader.info
            for _ in reader.frames(0, min(info.frames, FRAMES)):
                pass
    except EigenscopeError:
        pass
    finally:
        path.unlink(missing_ok=True)


def main() -> None:
    os.environ.setdefault("AV_LOG_FORCE_NOCOLOR", "1")
    import av

    av.logging.set_level(None)  # FFmpeg's complaints about broken inputs are expected, not findings
    atheris.Setup(sys.argv, read_clip)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
