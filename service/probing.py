"""Validate an uploaded clip by running :mod:`workers.probe` in a sandboxed child process.

The API process never imports the clip readers; a crash, hang or memory blow-up on a hostile file stays
in the child, which runs under resource limits and a wall-clock timeout.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from backend.errors import InvalidClipError, ServiceError, clip_error

log = logging.getLogger(__name__)

#: With ``EIGENSCOPE_TEST_HOOKS=1`` only: an upload whose file name starts with this is validated by a
#: probe that first waits :data:`SLOW_PROBE_HOLD_S` (fault-injection for the test suite).
SLOW_PROBE_MARKER = "__eigenscope_slow_probe__"
SLOW_PROBE_HOLD_S = 60.0

_PASS_ENV = ("PATH", "PYTHONPATH", "HOME", "LANG", "LC_ALL", "TMPDIR", "VIRTUAL_ENV")


def _command(path: Path, *, timeout_s: float, memory_mb: int, nice: int, hold_s: float) -> list[str]:
    """The probe's command line but for the caps."""
    cmd = [
        sys.executable,
        "-m",
        "workers.probe",
        str(path),
        "--memory-mb",
        str(memory_mb),
        "--cpu-s",
        str(int(timeout_s) + 1),
        "--nice",
        str(nice),
        "--parent-pid",
        str(os.getpid()),  # the probe dies with this process
    ]
    if hold_s > 0:
        cmd += ["--hold-s", repr(float(hold_s))]
    return cmd


@dataclass(frozen=True)
class ProbeCaps:
    """What a probed clip may hold and decode to (the readers' caps; None: the readers' own default).

    Attributes
    ----------
    max_frames, max_pixels : int or None
    max_decoded_mb : int or None
        Also bounds what a zip may expand to.
    max_inflation_ratio : float or None
    inflation_floor_mb : int or None
    """

    max_frames: int | None = None
    max_pixels: int | None = None
    max_decoded_mb: int | None = None
    max_inflation_ratio: float | None = None
    inflation_floor_mb: int | None = None

    def arguments(self) -> list[str]:
        """The probe command's options for these caps."""
        args: list[str] = []
        if self.max_frames is not None:
            args += ["--max-frames", str(self.max_frames)]
        if self.max_pixels is not None:
            args += ["--max-pixels", str(self.max_pixels)]
        if self.max_decoded_mb is not None:
            args += [
                "--max-decoded-mb",
                str(self.max_decoded_mb),
                "--max-unpacked-mb",
                str(self.max_decoded_mb),
            ]
        if self.max_inflation_ratio is not None:
            args += ["--max-inflation-ratio", repr(float(self.max_inflation_ratio))]
        if self.inflation_floor_mb is not None:
            args += ["--inflation-floor-mb", str(self.inflation_floor_mb)]
        return args


def probe_clip(
    path: Path,
    *,
    timeout_s: float,
    memory_mb: int,
    caps: ProbeCaps | None = None,
    scratch_dir: Path | None = None,
    nice: int = 10,
    hold_s: float = 0.0,
) -> dict[str, Any]:
    """Describe the clip at ``path`` (see :func:`workers.probe.probe`), or raise the matching API error.

    The probe dies with this process (a crashed API leaves no validator running); ``hold_s`` makes it
    wait that long first (the test hooks' stand-in for a long validation). The probe reads the clip under
    the same caps as an analysis (``caps``; its ``max_decoded_mb`` also bounds what a zip may expand to,
    and so what a zipped ROS 2 bag unpacks to in ``scratch_dir``).

    Raises
    ------
    ServiceError
        422 for a malformed clip or a probe that ran out of time, 415 for an unknown format, 413 for a
        clip over the readers' caps.
    """
    env = {k: v for k, v in os.environ.items() if k in _PASS_ENV}
    env.update({"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
    cmd = _command(path, timeout_s=timeout_s, memory_mb=memory_mb, nice=nice, hold_s=hold_s)
    cmd += (caps or ProbeCaps()).arguments()
    if scratch_dir is not None:
        cmd += ["--scratch-dir", str(scratch_dir)]
    try:
        proc = subprocess.run(
            cmd, capture_output=True, timeout=timeout_s, env=env, stdin=subprocess.DEVNULL, check=False
        )
    except subprocess.TimeoutExpired:
        raise InvalidClipError(
            f"the clip could not be validated within {timeout_s:g} s; it is malformed or far too large",
            code="probe-timeout",
        ) from None
    lines = proc.stdout.decode(errors="replace").strip().splitlines()
    try:
        doc = json.loads(lines[-1]) if lines else None
    except json.JSONDecodeError:
        doc = None
    if proc.returncode == 0 and isinstance(doc, dict) and "format" in doc:
        return doc
    if isinstance(doc, dict) and "code" in doc:
        if doc["code"] == "probe-failed":
            raise ServiceError(f"clip validation failed: {doc.get('detail')}", code="probe-failed")
        raise clip_error(str(doc["code"]), str(doc.get("detail") or "the clip is not valid"))
    stderr = proc.stderr.decode(errors="replace").strip()
    log.warning("probe of %s exited %s without a verdict: %s", path, proc.returncode, stderr[-2000:])
    if proc.returncode < 0:
        raise InvalidClipError(
            f"reading the clip crashed the validator (signal {-proc.returncode}); the file is malformed "
            "or exceeds the validator's memory/CPU limits",
            code="invalid-clip",
        )
    raise ServiceError("clip validation failed unexpectedly; see the server log", code="probe-failed")
