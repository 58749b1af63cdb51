"""The client's force log (``eigenscope_client.ForceLog``): what it sends is what the server's model takes,
it refuses what the server would, its pure-Python file reader reads every file as the pipeline's reader
does (``workers.pipeline.clipio.force_log``), and ``create_job`` sends it and reads the job's summary."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from eigenscope_client import Client, ForceLog, ForceLogError, ForceLogSummary

from api_schemas import ForceLog as ServerForceLog
from workers.pipeline.clipio.force_log import read_force_log
from workers.pipeline.errors import ForceError

TIMES = [round(i / 500 - 0.01, 6) for i in range(10)]
HELD = [6.0] * 5 + [0.0] * 5


def _csv(header: str, rows: list[str], sep: str = ",") -> bytes:
    return "\n".join([header.replace(",", sep), *(r.replace(",", sep) for r in rows)]).encode()


ROWS3 = [f"{t},{f},0.1,-0.2" for t, f in zip(TIMES, HELD, strict=True)]
ROWS1 = [f"{t},{f}" for t, f in zip(TIMES, HELD, strict=True)]
SAMPLES = [{"time_s": t, "fx": f, "fy": 0.1, "fz": -0.2} for t, f in zip(TIMES, HELD, strict=True)]

#: Files both readers take.
ACCEPTED: dict[str, bytes] = {
    "components.csv": b"# robot 3, wrist sensor\n# frame_id: ft_sensor_link\n\n"
    + _csv("time_s,fx,fy,fz,torque_x", [r + ",0" for r in ROWS3]),
    "magnitude.csv": _csv("Time_S,Force_N", ROWS1, ";"),
    "tabs.txt": _csv("time_s,force_n", ROWS1, "\t"),
    "bom.csv": b"\xef\xbb\xbf" + _csv("time_s,fx,fy,fz", ROWS3),
    "columns.json": json.dumps(
        {"time_s": TIMES, "fx": HELD, "fy": [0.1] * 10, "fz": [-0.2] * 10, "frame_id": "ft"}
    ).encode(),
    "samples.json": json.dumps({"samples": SAMPLES}).encode(),
    "bare.log": json.dumps([{"TIME_S": t, "force_n": f} for t, f in zip(TIMES, HELD, strict=True)]).encode(),
    "strings.json": json.dumps({"time_s": [str(t) for t in TIMES], "force_n": HELD}).encode(),
}
#: Files both refuse.
REFUSED: dict[str, bytes] = {
    "empty.csv": b"  \n",
    "binary.csv": b"\x00\x01\x02time_s",
    "not-utf8.csv": b"time_s,force_n\n\xff\xfe,1\n",
    "no-force.csv": _csv("time_s,torque", ROWS1),
    "ragged.csv": _csv("time_s,force_n", [*ROWS1[:4], "0.5,1,2", *ROWS1[4:]]),
    "text.csv": _csv("time_s,force_n", [*ROWS1[:3], "0.1,heavy", *ROWS1[4:]]),
    "nan.csv": _csv("time_s,force_n", [*ROWS1[:3], f"{TIMES[3]},nan", *ROWS1[4:]]),
    "backwards.csv": _csv("time_s,force_n", [ROWS1[1], ROWS1[0], *ROWS1[2:]]),
    "repeated.csv": _csv("time_s,force_n", [ROWS1[0], *ROWS1[:-1]]),
    "few.csv": _csv("time_s,force_n", ROWS1[:5]),
    "bad.json": b'{"time_s": [0, 1',
    "samples.json": b'{"samples": [1, 2, 3]}',
    "lengths.json": json.dumps({"time_s": TIMES, "force_n": HELD[:-1]}).encode(),
    "nulls.json": json.dumps({"time_s": TIMES, "force_n": [None] * 10}).encode(),
    "deep.json": b"[" * 100_000,
}


@pytest.mark.parametrize("name", ACCEPTED)
def test_the_client_reads_a_file_as_the_pipeline_does(name: str) -> None:
    data = ACCEPTED[name]
    series = read_force_log(data, name=name, offset_s=-0.25)
    log = ForceLog.from_bytes(data, name=name, offset_s=-0.25)
    assert log.name == name
    assert log.offset_s == -0.25
    assert log.frame_id == series.frame_id
    np.testing.assert_array_equal(np.asarray(log.time_s) + log.offset_s, series.times_s)
    force = np.stack([np.asarray(getattr(log, c)) for c in log.columns], axis=1)
    np.testing.assert_array_equal(force, series.force_n)
    # What it sends is what the server's model takes, unchanged.
    sent = ServerForceLog.model_validate(log.to_dict())
    assert sent.time_s == list(log.time_s)
    assert sent.offset_s == -0.25
    assert sent.name == name


@pytest.mark.parametrize("name", REFUSED)
def test_the_client_refuses_a_file_as_the_pipeline_does(name: str) -> None:
    data = REFUSED[name]
    with pytest.raises(ForceError):
        read_force_log(data, name=name)
    with pytest.raises(ForceLogError) as refused:
        ForceLog.from_bytes(data, name=name)
    assert isinstance(refused.value, ValueError)
    assert name in str(refused.value)


@pytest.mark.parametrize(
    ("columns", "words"),
    [
        ({"time_s": TIMES, "fx": HELD, "fy": HELD, "fz": HELD[:-1]}, "fz has 9 values but time_s has 10"),
        ({"time_s": TIMES, "fx": HELD, "fy": HELD}, "all three of fx, fy and fz"),
        ({"time_s": TIMES, "force_n": HELD, "fx": HELD, "fy": HELD, "fz": HELD}, "not both"),
        ({"time_s": TIMES[::-1], "force_n": HELD}, "time_s[1] = "),
        ({"time_s": TIMES, "force_n": [*HELD[:-1], float("inf")]}, "force_n[9] is inf"),
        ({"time_s": TIMES[:7], "force_n": HELD[:7]}, "7 samples"),
        ({"time_s": TIMES, "force_n": ["six"] * 10}, "force_n must be a sequence of numbers"),
    ],
    ids=["a-short-column", "two-components", "both-forms", "backwards", "infinite", "too-few", "text"],
)
def test_a_log_the_server_would_refuse_is_refused_before_it_is_sent(
    columns: dict[str, Any], words: str
) -> None:
    with pytest.raises(ForceLogError, match=words.replace("[", r"\[").replace("]", r"\]")):
        ForceLog(**columns)
    # ... and the server's model refuses it too.
    with pytest.raises(ValueError, match=r"."):
        ServerForceLog.model_validate(columns)


def test_the_model_round_trips_through_the_servers() -> None:
    log = ForceLog(
        time_s=TIMES, fx=HELD, fy=[0.1] * 10, fz=[-0.2] * 10, offset_s=1.5, frame_id="ft", name="p"
    )
    doc = log.to_dict()
    assert doc == {
        "time_s": TIMES,
        "fx": HELD,
        "fy": [0.1] * 10,
        "fz": [-0.2] * 10,
        "offset_s": 1.5,
        "frame_id": "ft",
        "name": "p",
    }
    server = ServerForceLog.model_validate(doc)
    assert server.model_dump(exclude_none=True) == doc
    assert ForceLog(**server.model_dump(exclude_none=True)) == log
    summary = server.summary().model_dump(mode="json")
    assert ForceLogSummary.from_dict(summary) == ForceLogSummary(
        name="p",
        samples=10,
        start_s=1.49,
        end_s=pytest.approx(1.49 + 9 / 500),
        columns=["fx", "fy", "fz"],
        frame_id="ft",
    )


def test_create_job_sends_the_log_and_reads_its_summary(tmp_path: Path) -> None:
    seen: list[dict[str, Any]] = []
    summary = {"name": "push.csv", "samples": 10, "start_s": -0.01, "end_s": 0.008, "columns": ["force_n"]}

    def handler(request: httpx.Request) -> httpx.Response:
        body = json.loads(request.read())
        seen.append(body)
        job = {
            "id": "j1",
            "clip_id": body["clip_id"],
            "status": "queued",
            "progress": 0.0,
            "parameters": {},
            "created_at": "2026-01-01T00:00:00Z",
            "force_log": {**summary, "frame_id": None},
        }
        return httpx.Response(202, json=job)

    path = tmp_path / "push.csv"
    path.write_bytes(_csv("time_s,force_n", ROWS1))
    http = httpx.Client(transport=httpx.MockTransport(handler))
    with Client("http://eigenscope.test", http_client=http) as client:
        job = client.create_job("c1", force_log=ForceLog.from_file(path), parameters={"depth_m": 0.9})
    assert seen[0]["force_log"] == {"time_s": TIMES, "force_n": HELD, "offset_s": 0.0, "name": "push.csv"}
    assert "excitation" not in seen[0]
    assert job.force_log == ForceLogSummary(**summary)


def test_the_reader_needs_no_numpy(tmp_path: Path) -> None:
    """The client stays dependency-light: reading a log loads neither numpy nor the pipeline."""
    path = tmp_path / "push.json"
    path.write_bytes(ACCEPTED["columns.json"])
    code = (
        "import sys; from eigenscope_client import ForceLog; "
        f"log = ForceLog.from_file({str(path)!r}); "
        "print(len(log.time_s), sorted(m for m in ('numpy', 'workers', 'pydantic') if m in sys.modules))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["10", "[]"]
