"""Force logs beside a clip: a CSV or JSON time series of the force a robot applied, read into a
:class:`~workers.pipeline.force.ForceSeries` on the clip's clock (see :func:`read_force_log`)."""

from __future__ import annotations

import csv
import json
import math
import re
from typing import Any

import numpy as np

from workers.pipeline.errors import ForceError
from workers.pipeline.force import FloatArray, ForceSeries


def read_force_log(data: bytes, *, name: str, offset_s: float = 0.0) -> ForceSeries:
    """Read a force log (CSV or JSON) into a :class:`ForceSeries`.

    Accepted forms (column names are case-insensitive; other columns are ignored):

    - CSV: a header line with ``time_s`` and either ``fx,fy,fz`` (N, the sensor's frame) or ``force_n``
      (one signed magnitude, N), then one sample a line. Blank lines and lines starting with ``#`` are
      skipped; a comment ``# frame_id: NAME`` names the sensor's frame. Comma, semicolon or tab separated.
    - JSON: columns ``{"time_s": [...], "fx": [...], "fy": [...], "fz": [...]}`` (or ``"force_n"``), or
      samples ``{"samples": [{"time_s": 0.0, "fx": ...}, ...]}`` (or a bare list of such samples). An
      optional ``"frame_id"`` names the sensor's frame.

    JSON is recognised by a ``.json`` name or a first character ``{`` or ``[``; anything else is CSV.

    Time origin: ``time_s`` is seconds on the clip's clock, 0 being the clip's first frame (negative
    before it). A log kept on another clock needs ``offset_s``, which is added to every time:
    ``offset_s = -(the log's time at the clip's first frame)``; a log whose clock reads 12.5 s when the
    clip's first frame is taken needs ``offset_s=-12.5``.

    Parameters
    ----------
    data : bytes
        The file's content, UTF-8 (a byte-order mark is allowed).
    name : str
        The file's name, for the format and for messages; the source becomes ``"log NAME"``.
    offset_s : float
        Seconds added to every time (see above).

    Returns
    -------
    ForceSeries
        ``force_n`` of shape (N, 3) for ``fx, fy, fz``, (N, 1) for ``force_n``.

    Raises
    ------
    ForceError
        Not text, not valid JSON, missing columns (the message lists the accepted ones), a value that is
        not a number or not finite, times that run backwards, fewer than
        :data:`~workers.pipeline.force_baseline.MIN_SAMPLES` samples.
    """
    if not math.isfinite(offset_s):
        raise ForceError(f"the force log {name}'s offset_s is {offset_s}; give a finite number of seconds")
    text = _decoded(data, name=name)
    if name.lower().endswith(".json") or text.lstrip()[:1] in ("{", "["):
        columns, frame_id = _json_columns(text, name=name)
    else:
        columns, frame_id = _csv_columns(text, name=name)
    times, force = _force_columns(columns, name=name)
    return ForceSeries(times_s=times + offset_s, force_n=force, source=f"log {name}", frame_id=frame_id)


def _decoded(data: bytes, *, name: str) -> str:
    """The log's text, or a ForceError when it is not UTF-8 text."""
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        text = "\x00"
    if "\x00" in text or not text.strip():
        raise ForceError(
            f"the force log {name} is {'empty' if not text.strip() else 'not UTF-8 text'}; give a CSV "
            "(header time_s,fx,fy,fz or time_s,force_n) or a JSON log"
        )
    return text


def _csv_columns(text: str, *, name: str) -> tuple[dict[str, list[Any]], str | None]:
    """CSV text as columns by lower-case header name, and the ``# frame_id:`` comment's frame."""
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
        raise ForceError(f"the force log {name} has no header and no samples; {_ACCEPTED}")
    header = lines[0][1]
    delimiter = "\t" if "\t" in header else ";" if ";" in header and "," not in header else ","
    rows = list(csv.reader([line for _, line in lines], delimiter=delimiter))
    names = [cell.strip().lower() for cell in rows[0]]
    columns: dict[str, list[Any]] = {column: [] for column in names}
    for (number, _), row in zip(lines[1:], rows[1:], strict=True):
        if len(row) != len(names):
            raise ForceError(
                f"the force log {name}: line {number} has {len(row)} fields, the header {len(names)}; "
                "give every sample a value for every column"
            )
        for column, cell in zip(names, row, strict=True):
            columns[column].append(cell.strip())
    return columns, frame_id


def _json_columns(text: str, *, name: str) -> tuple[dict[str, list[Any]], str | None]:
    """JSON text (columns, ``samples`` or a list of samples) as columns by lower-case name."""
    try:
        content = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ForceError(
            f"the force log {name} is not valid JSON ({exc.msg} at line {exc.lineno}); {_ACCEPTED}"
        ) from None
    except RecursionError:
        raise ForceError(f"the force log {name} nests too deeply to be a force log; {_ACCEPTED}") from None
    frame_id = content.get("frame_id") if isinstance(content, dict) else None
    samples = content.get("samples") if isinstance(content, dict) else content
    if isinstance(content, dict) and samples is None:
        columns = {str(key).lower(): value for key, value in content.items() if isinstance(value, list)}
        return columns, frame_id if isinstance(frame_id, str) else None
    if not isinstance(samples, list) or not all(isinstance(sample, dict) for sample in samples):
        raise ForceError(f"the force log {name}'s samples must be a list of objects; {_ACCEPTED}")
    keys = {str(key).lower() for sample in samples for key in sample}
    columns = {key: [] for key in keys}
    for sample in samples:
        lowered = {str(key).lower(): value for key, value in sample.items()}
        for key in keys:
            columns[key].append(lowered.get(key))
    return columns, frame_id if isinstance(frame_id, str) else None


_ACCEPTED = (
    "accepted: a CSV with a header time_s,fx,fy,fz (or time_s,force_n), or JSON "
    '{"time_s": [...], "fx": [...], "fy": [...], "fz": [...]} (or "force_n"), or '
    '{"samples": [{"time_s": ..., "fx": ..., "fy": ..., "fz": ...}, ...]}'
)


def _force_columns(columns: dict[str, list[Any]], *, name: str) -> tuple[FloatArray, FloatArray]:
    """``time_s`` (N,) and ``fx, fy, fz`` (N, 3) or ``force_n`` (N, 1) as numbers."""
    if "time_s" in columns and all(axis in columns for axis in ("fx", "fy", "fz")):
        wanted = ["fx", "fy", "fz"]
    elif "time_s" in columns and "force_n" in columns:
        wanted = ["force_n"]
    else:
        found = ", ".join(sorted(columns)) or "none"
        raise ForceError(f"the force log {name} lacks the columns it needs (found: {found}); {_ACCEPTED}")
    lengths = {column: len(columns[column]) for column in ["time_s", *wanted]}
    if len(set(lengths.values())) > 1:
        raise ForceError(
            f"the force log {name}'s columns differ in length ({lengths}); give every column one value "
            "per sample"
        )
    times = _numbers(columns["time_s"], column="time_s", name=name)
    force = np.stack([_numbers(columns[column], column=column, name=name) for column in wanted], axis=1)
    return times, force


def _numbers(values: list[Any], *, column: str, name: str) -> FloatArray:
    """A column's values as float64 (N,); a value that is not a number is an error naming its row."""
    out = np.empty(len(values), dtype=np.float64)
    for row, value in enumerate(values):
        try:
            if isinstance(value, bool) or value is None:
                raise TypeError
            out[row] = float(value)
        except (TypeError, ValueError):
            raise ForceError(
                f"the force log {name}: row {row + 1}, column {column}: {value!r} is not a number; "
                "give a number (seconds or newtons) in every cell"
            ) from None
    return out


__all__ = ["read_force_log"]
