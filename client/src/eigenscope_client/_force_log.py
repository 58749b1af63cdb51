"""Force logs beside a clip: the robot's force sensor as a time series, sent with a job
(:class:`ForceLog`), read from a CSV or JSON file in pure Python (:meth:`ForceLog.from_file`).

The file formats are the server's and ``eigenscope analyze --force-log``'s
(``workers.pipeline.clipio.force_log``; a test holds the two readers to the same answers):

- CSV: a header line with ``time_s`` and either ``fx,fy,fz`` (N, the sensor's frame) or ``force_n`` (one
  signed magnitude, N), then one sample a line. Column names are case-insensitive; other columns are
  ignored; blank lines and lines starting with ``#`` are skipped; a comment ``# frame_id: NAME`` names the
  sensor's frame. Comma, semicolon or tab separated.
- JSON: columns ``{"time_s": [...], "fx": [...], "fy": [...], "fz": [...]}`` (or ``"force_n"``), or
  samples ``{"samples": [{"time_s": 0.0, "fx": ...}, ...]}`` (or a bare list of such samples). An optional
  ``"frame_id"`` names the sensor's frame.

Time origin: 0 is the clip's first frame. A log on another clock needs ``offset_s`` (added to every time):
minus the log's time at the clip's first frame.
"""

from __future__ import annotations

import csv
import json
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from eigenscope_client._errors import ForceLogError

#: Fewest and most samples a log may have (the server's limits).
MIN_FORCE_SAMPLES = 8
MAX_FORCE_SAMPLES = 200_000

_ACCEPTED = (
    "accepted: a CSV with a header time_s,fx,fy,fz (or time_s,force_n), or JSON "
    '{"time_s": [...], "fx": [...], "fy": [...], "fz": [...]} (or "force_n"), or '
    '{"samples": [{"time_s": ..., "fx": ..., "fy": ..., "fz": ...}, ...]}'
)


def _floats(values: Sequence[Any] | None, column: str) -> tuple[float, ...] | None:
    if values is None:
        return None
    try:
        out = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise ForceLogError(f"force log: {column} must be a sequence of numbers") from None
    return out


@dataclass(frozen=True)
class ForceLog:
    """A force sensor's log sent with a job (``create_job(..., force_log=...)``): its push, hold and
    release, or its strike, is the excitation; a typed ``excitation`` overrides it.

    Give the three components ``fx``, ``fy``, ``fz`` (newtons, the sensor's frame; the force along its
    dominant direction is used) or one signed magnitude ``force_n``, each with one value per time in
    ``time_s`` (seconds, strictly increasing, 0 = the clip's first frame). ``offset_s`` is added to every
    time: minus the log's time at the clip's first frame. ``name`` is where it came from (the result's
    ``excitation.source`` reads ``log NAME``).

    Raises
    ------
    ForceLogError
        A log the server would refuse: both or neither form, a column not one value per time, fewer than
        8 or more than 200,000 samples, a value that is not finite, times that do not increase.
    """

    time_s: Sequence[float]
    fx: Sequence[float] | None = None
    fy: Sequence[float] | None = None
    fz: Sequence[float] | None = None
    force_n: Sequence[float] | None = None
    offset_s: float = 0.0
    frame_id: str | None = None
    name: str = "force log"

    #: The OpenAPI schema this class mirrors.
    schema: ClassVar[str] = "ForceLog"

    def __post_init__(self) -> None:
        for column in ("time_s", "fx", "fy", "fz", "force_n"):
            object.__setattr__(self, column, _floats(getattr(self, column), column))
        times: tuple[float, ...] = self.time_s  # type: ignore[assignment]
        components = [c for c in (self.fx, self.fy, self.fz) if c is not None]
        if self.force_n is not None and components:
            raise ForceLogError("force log: give either fx, fy and fz or force_n, not both")
        if self.force_n is None and len(components) != 3:
            raise ForceLogError("force log: give all three of fx, fy and fz, or force_n alone")
        if not MIN_FORCE_SAMPLES <= len(times) <= MAX_FORCE_SAMPLES:
            raise ForceLogError(
                f"force log {self.name}: {len(times)} samples; give between {MIN_FORCE_SAMPLES} and "
                f"{MAX_FORCE_SAMPLES} (a few hundred around the push or strike)"
            )
        for column in self.columns:
            values: tuple[float, ...] = getattr(self, column)
            if len(values) != len(times):
                raise ForceLogError(
                    f"force log {self.name}: {column} has {len(values)} values but time_s has {len(times)}; "
                    "give one value per time"
                )
        for column in ("time_s", *self.columns):
            values = getattr(self, column)
            bad = next((i for i, v in enumerate(values) if not math.isfinite(v)), None)
            if bad is not None:
                raise ForceLogError(
                    f"force log {self.name}: {column}[{bad}] is {values[bad]}; remove or repair the samples "
                    "that are not finite"
                )
        if not math.isfinite(self.offset_s):
            raise ForceLogError(f"force log {self.name}: offset_s is {self.offset_s}; give a finite number")
        object.__setattr__(self, "offset_s", float(self.offset_s))
        for i in range(1, len(times)):
            if not times[i] > times[i - 1]:
                how = "repeats" if times[i] == times[i - 1] else "runs backwards from"
                raise ForceLogError(
                    f"force log {self.name}: times must increase strictly, but time_s[{i}] = "
                    f"{times[i]:.9g} s {how} time_s[{i - 1}] = {times[i - 1]:.9g} s; sort the samples by "
                    "time and drop repeated ones, or fix the sensor's clock"
                )

    @property
    def columns(self) -> list[str]:
        """The force's columns: ``["fx", "fy", "fz"]`` or ``["force_n"]``."""
        return ["force_n"] if self.force_n is not None else ["fx", "fy", "fz"]

    def to_dict(self) -> dict[str, Any]:
        """The request's ``force_log`` member."""
        doc: dict[str, Any] = {"time_s": list(self.time_s)}
        for column in self.columns:
            doc[column] = list(getattr(self, column))
        doc["offset_s"] = self.offset_s
        if self.frame_id is not None:
            doc["frame_id"] = self.frame_id
        doc["name"] = self.name
        return doc

    @classmethod
    def from_file(
        cls, path: str | os.PathLike[str], *, offset_s: float = 0.0, name: str | None = None
    ) -> ForceLog:
        """Read a CSV or JSON force log (see the module docstring); ``name`` defaults to the file's.

        Raises
        ------
        OSError
            The file cannot be read.
        ForceLogError
            It is not a force log (the message says what is wrong and what is accepted).
        """
        file = Path(path)
        return cls.from_bytes(file.read_bytes(), name=name or file.name, offset_s=offset_s)

    @classmethod
    def from_bytes(cls, data: bytes, *, name: str, offset_s: float = 0.0) -> ForceLog:
        """A force log from a file's content (``name`` tells JSON by a ``.json`` ending; see
        :meth:`from_file`)."""
        columns, frame_id = read_columns(data, name=name)
        return cls(**columns, offset_s=offset_s, frame_id=frame_id, name=name)


def read_columns(data: bytes, *, name: str) -> tuple[dict[str, list[float]], str | None]:
    """A force log file's ``time_s`` and force columns as numbers, and its sensor frame (or None).

    Raises
    ------
    ForceLogError
        Not UTF-8 text, not valid JSON, missing columns, columns of different lengths, a value that is not
        a number.
    """
    text = _decoded(data, name=name)
    if name.lower().endswith(".json") or text.lstrip()[:1] in ("{", "["):
        columns, frame_id = _json_columns(text, name=name)
    else:
        columns, frame_id = _csv_columns(text, name=name)
    return _force_columns(columns, name=name), frame_id


def _decoded(data: bytes, *, name: str) -> str:
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = "\x00"
    if "\x00" in text or not text.strip():
        raise ForceLogError(
            f"the force log {name} is {'empty' if not text.strip() else 'not UTF-8 text'}; give a CSV "
            "(header time_s,fx,fy,fz or time_s,force_n) or a JSON log"
        )
    return text


def _csv_columns(text: str, *, name: str) -> tuple[dict[str, list[Any]], str | None]:
    frame_id = None
    lines: list[tuple[int, str]] = []
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        found = re.match(r"#\s*frame_id\s*[:=]\s*(\S+)", stripped)
        if found:
            frame_id = found.group(1)
        if stripped and not stripped.startswith("#"):
            lines.append((number, stripped))
    if not lines:
        raise ForceLogError(f"the force log {name} has no header and no samples; {_ACCEPTED}")
    header = lines[0][1]
    delimiter = "\t" if "\t" in header else ";" if ";" in header and "," not in header else ","
    rows = list(csv.reader([line for _, line in lines], delimiter=delimiter))
    names = [cell.strip().lower() for cell in rows[0]]
    columns: dict[str, list[Any]] = {column: [] for column in names}
    for (number, _), row in zip(lines[1:], rows[1:], strict=True):
        if len(row) != len(names):
            raise ForceLogError(
                f"the force log {name}: line {number} has {len(row)} fields, the header {len(names)}; "
                "give every sample a value for every column"
            )
        for column, cell in zip(names, row, strict=True):
            columns[column].append(cell.strip())
    return columns, frame_id


def _json_columns(text: str, *, name: str) -> tuple[dict[str, list[Any]], str | None]:
    try:
        content = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ForceLogError(
            f"the force log {name} is not valid JSON ({exc.msg} at line {exc.lineno}); {_ACCEPTED}"
        ) from None
    except RecursionError:
        raise ForceLogError(f"the force log {name} nests too deeply to be a force log; {_ACCEPTED}") from None
    frame_id = content.get("frame_id") if isinstance(content, dict) else None
    samples = content.get("samples") if isinstance(content, dict) else content
    if isinstance(content, dict) and samples is None:
        columns = {str(key).lower(): value for key, value in content.items() if isinstance(value, list)}
        return columns, frame_id if isinstance(frame_id, str) else None
    if not isinstance(samples, list) or not all(isinstance(sample, dict) for sample in samples):
        raise ForceLogError(f"the force log {name}'s samples must be a list of objects; {_ACCEPTED}")
    keys = {str(key).lower() for sample in samples for key in sample}
    columns = {key: [] for key in keys}
    for sample in samples:
        lowered = {str(key).lower(): value for key, value in sample.items()}
        for key in keys:
            columns[key].append(lowered.get(key))
    return columns, frame_id if isinstance(frame_id, str) else None


def _force_columns(columns: dict[str, list[Any]], *, name: str) -> dict[str, list[float]]:
    if "time_s" in columns and all(axis in columns for axis in ("fx", "fy", "fz")):
        wanted = ["fx", "fy", "fz"]
    elif "time_s" in columns and "force_n" in columns:
        wanted = ["force_n"]
    else:
        found = ", ".join(sorted(columns)) or "none"
        raise ForceLogError(f"the force log {name} lacks the columns it needs (found: {found}); {_ACCEPTED}")
    lengths = {column: len(columns[column]) for column in ["time_s", *wanted]}
    if len(set(lengths.values())) > 1:
        raise ForceLogError(
            f"the force log {name}'s columns differ in length ({lengths}); give every column one value "
            "per sample"
        )
    return {column: _numbers(columns[column], column=column, name=name) for column in ["time_s", *wanted]}


def _numbers(values: list[Any], *, column: str, name: str) -> list[float]:
    out = []
    for row, value in enumerate(values):
        try:
            if isinstance(value, bool) or value is None:
                raise TypeError
            out.append(float(value))
        except (TypeError, ValueError):
            raise ForceLogError(
                f"the force log {name}: row {row + 1}, column {column}: {value!r} is not a number; "
                "give a number (seconds or newtons) in every cell"
            ) from None
    return out
