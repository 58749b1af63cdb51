"""The force sensor as the excitation (:mod:`workers.pipeline.force`): synthetic force records with a known
held force, release instant or impulse, and the bounds the measurement must meet; the logs it reads and
the errors it gives."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from workers.pipeline.clipio.force_log import read_force_log
from workers.pipeline.errors import ForceError, ParameterError
from workers.pipeline.force import (
    ForceSeries,
    dominant_direction,
    excitation_of,
    find_excitation,
)
from workers.pipeline.model import Excitation

HELD_N = 5.0


def _push_hold_release(
    *,
    rate_hz: float = 500.0,
    noise_n: float = 0.05,
    held_n: float = HELD_N,
    release_s: float = 2.0,
    drop_s: float = 0.004,
    drift_n: float = 0.0,
    start_s: float = -0.3,
    duration_s: float = 4.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Times (N,) and force (N,): rest until 0.4 s, a 0.3 s raised-cosine push to ``held_n``, held, then a
    raised-cosine drop over ``drop_s`` (0: a step) centred on ``release_s``, where the force crosses half
    the held force; plus a linear drift over the record and white noise."""
    rng = np.random.default_rng(seed)
    t = start_s + np.arange(round(duration_s * rate_hz)) / rate_hz
    ramp = np.clip((t - 0.4) / 0.3, 0.0, 1.0)
    force = held_n * 0.5 * (1 - np.cos(np.pi * ramp))
    if drop_s > 0:
        drop = np.clip((t - release_s + drop_s / 2) / drop_s, 0.0, 1.0)
        force *= 0.5 * (1 + np.cos(np.pi * drop))
    else:
        force[t >= release_s] = 0.0
    force += drift_n * (t - t[0]) / (t[-1] - t[0])
    return t, force + noise_n * rng.standard_normal(t.size)


def _strike(
    *,
    rate_hz: float,
    centre_s: float,
    noise_n: float = 0.05,
    peak_n: float = 20.0,
    width_s: float = 0.009,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, float]:
    """Times (N,), force (N,) and impulse: a half-sine pulse ``width_s`` long centred on ``centre_s``."""
    rng = np.random.default_rng(seed)
    t = -0.2 + np.arange(round(3.0 * rate_hz)) / rate_hz
    inside = np.abs(t - centre_s) < width_s / 2
    force = np.where(inside, peak_n * np.cos(np.pi * (t - centre_s) / width_s), 0.0)
    return t, force + noise_n * rng.standard_normal(t.size), 2 * peak_n * width_s / math.pi


def _series(times: np.ndarray, force: np.ndarray, **kwargs: object) -> ForceSeries:
    return ForceSeries(times_s=times, force_n=force, source="log test.csv", **kwargs)  # type: ignore[arg-type]


def _csv(times: np.ndarray, force: np.ndarray) -> bytes:
    """A CSV log: time_s,fx,fy,fz for (N, 3) force, time_s,force_n for (N,)."""
    header = "time_s,fx,fy,fz" if force.ndim == 2 else "time_s,force_n"
    rows = np.column_stack([times, force])
    lines = ["# a wrist force log", "# frame_id: ft_sensor_link", header]
    lines += [",".join(f"{value:.9g}" for value in row) for row in rows]
    return ("\n".join(lines) + "\n").encode()


# --- push, hold, release -------------------------------------------------------------------------------


@pytest.mark.parametrize("drop_s", [0.004, 0.0], ids=["4-ms-release", "instant-release"])
def test_push_hold_release_gives_the_held_force_within_2_percent_and_the_release_within_1_ms(drop_s):
    release_s = 2.0 + 0.37 / 500  # between two samples
    t, f = _push_hold_release(release_s=release_s, drop_s=drop_s, seed=1)
    found = find_excitation(_series(t, f))
    assert found.kind == "step_release"
    assert abs(found.value / HELD_N - 1) < 0.02, found.value
    assert abs(found.time_s - release_s) < 1e-3, found.time_s - release_s
    assert found.hold_s is not None
    assert 0.69 < found.hold_s[0] < 0.8
    assert release_s - 0.01 < found.hold_s[1] < release_s
    assert found.direction is None
    assert found.pulse_s is None
    excitation = excitation_of(found)
    assert isinstance(excitation, Excitation)
    assert (excitation.kind, excitation.value, excitation.uncertainty) == (
        "step_release",
        found.value,
        found.uncertainty,
    )


def test_a_smooth_release_is_timed_far_better_than_one_sample():
    errors = []
    for seed in range(10):
        release_s = 2.0 + np.random.default_rng(seed).uniform(0, 1 / 500)
        t, f = _push_hold_release(release_s=release_s, seed=seed)
        errors.append(find_excitation(_series(t, f)).time_s - release_s)
    assert np.max(np.abs(errors)) < 0.25e-3, errors


def test_a_push_read_as_negative_is_turned_positive_and_noted():
    t, f = _push_hold_release(seed=2)
    found = find_excitation(_series(t, -f))
    assert found.kind == "step_release"
    assert abs(found.value / HELD_N - 1) < 0.02
    assert any("sign was flipped" in note for note in found.notes)
    _, projected = dominant_direction(_series(t, -f))
    np.testing.assert_array_equal(projected, f)


def test_a_record_that_starts_during_the_hold_still_gives_the_held_force():
    t, f = _push_hold_release(seed=3)
    keep = t > 1.0
    found = find_excitation(_series(t[keep], f[keep]))
    assert found.kind == "step_release"
    assert abs(found.value / HELD_N - 1) < 0.02
    assert abs(found.time_s - 2.0) < 1e-3


# --- strike -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("rate_hz", [500.0, 1000.0])
def test_a_9_ms_strike_gives_the_impulse_within_3_percent(rate_hz):
    for k, phase in enumerate(np.linspace(0, 1, 5, endpoint=False)):
        centre_s = 1.23 + phase / rate_hz
        t, f, impulse = _strike(rate_hz=rate_hz, centre_s=centre_s, seed=k)
        found = find_excitation(_series(t, f))
        assert found.kind == "impulse"
        assert abs(found.value / impulse - 1) < 0.03, (phase, found.value / impulse - 1)
        assert abs(found.time_s - centre_s) < 1e-3
        assert found.pulse_s is not None
        assert found.pulse_s[0] < centre_s - 0.004
        assert found.pulse_s[1] > centre_s + 0.004
        assert found.hold_s is None
        assert excitation_of(found).kind == "impulse"


def test_a_ringing_sensor_after_a_strike_is_part_of_the_same_strike():
    t, f, impulse = _strike(rate_hz=1000.0, centre_s=1.2345)
    after = t - (1.2345 + 0.0045)
    ring = np.where(after > 0, 3 * np.exp(-80 * after) * np.sin(2 * np.pi * 150 * after), 0.0)
    found = find_excitation(_series(t, f + ring))
    assert found.kind == "impulse"
    assert not any("other excitation" in note for note in found.notes), found.notes
    assert abs(found.value / (impulse + np.trapezoid(ring, t)) - 1) < 0.03


# --- direction, drift, forcing, nothing ---------------------------------------------------------------


def test_a_rotated_sensor_frame_gives_the_same_held_force_as_the_magnitude():
    rng = np.random.default_rng(11)
    axis = rng.standard_normal(3)
    axis /= np.linalg.norm(axis)
    t, magnitude = _push_hold_release(noise_n=0.0, seed=4)
    noise = 0.05 * rng.standard_normal((t.size, 3))
    force = magnitude[:, None] * axis + np.array([0.3, -1.2, 4.0]) + noise  # a tool's weight as offset
    found = find_excitation(_series(t, force, frame_id="ft_sensor_link"))
    reference = find_excitation(_series(t, magnitude + noise @ axis))
    assert found.kind == "step_release"
    assert abs(found.value / HELD_N - 1) < 0.02
    assert abs(found.value - reference.value) < 3 * math.hypot(found.uncertainty, reference.uncertainty)
    assert abs(found.time_s - 2.0) < 1e-3
    assert found.direction is not None
    assert found.direction @ axis > 0.999
    assert any("no transform recorded" in note and "ft_sensor_link" in note for note in found.notes)
    direction, projected = dominant_direction(_series(t, force))
    assert direction is not None
    assert math.isclose(float(np.linalg.norm(direction)), 1.0)
    np.testing.assert_allclose(projected, force @ direction)
    in_camera = find_excitation(_series(t, force, in_camera_frame=True))
    assert not any("no transform" in note for note in in_camera.notes)


def test_a_noisy_drifting_sensor_gives_the_held_force_within_5_percent():
    t, f = _push_hold_release(noise_n=0.2, drift_n=0.5, seed=5)
    found = find_excitation(_series(t, f))
    assert found.kind == "step_release"
    assert abs(found.value / HELD_N - 1) < 0.05, found.value
    assert abs(found.time_s - 2.0) < 1e-3


def test_a_large_drift_is_removed_and_noted():
    t, f = _push_hold_release(noise_n=0.05, drift_n=1.5, seed=6)
    found = find_excitation(_series(t, f))
    assert abs(found.value / HELD_N - 1) < 0.02
    assert any("drifted" in note for note in found.notes)


def test_a_force_that_keeps_oscillating_is_a_forced_vibration_that_carries_its_samples():
    t = np.arange(0, 4, 1 / 500)
    swing = np.where(t > 0.5, 2.0 * np.sin(2 * np.pi * 6 * (t - 0.5)), 0.0)
    f = 1.0 + swing + 0.05 * np.random.default_rng(7).standard_normal(t.size)
    series = _series(t, f)
    found = find_excitation(series)
    assert found.kind == "forced"
    assert abs(found.value / (2.0 / math.sqrt(2)) - 1) < 0.05
    assert abs(found.time_s - 0.5) < 1 / 6
    (note,) = [note for note in found.notes if "forced vibration" in note]
    frequency = re.search(r"about ([0-9.]+) Hz", note)
    assert frequency is not None, note
    assert abs(float(frequency.group(1)) / 6.0 - 1) < 0.02, note
    excitation = excitation_of(found)
    assert excitation.kind == "forced"
    assert excitation.release_time_s is None
    assert excitation.force_times_s is not None
    assert excitation.force_along_n is not None
    np.testing.assert_array_equal(excitation.force_times_s, t)
    assert abs(np.std(excitation.force_along_n[t > 0.5]) / math.sqrt(2) - 1) < 0.05  # the 2 N swing, 1-D


def test_pure_noise_has_no_excitation_and_says_what_to_do():
    t = np.arange(0, 3, 1 / 500)
    noise = 0.05 * np.random.default_rng(8).standard_normal((t.size, 3)) + [1.0, 2.0, 3.0]
    with pytest.raises(ForceError) as raised:
        find_excitation(_series(t, noise))
    message = str(raised.value)
    assert "no hold, release or strike above its noise" in message
    assert "--force-n / --impulse-ns" in message
    assert "--force-topic" in message


# --- several events and the window ---------------------------------------------------------------------


def _two_pushes() -> tuple[np.ndarray, np.ndarray]:
    t, first = _push_hold_release(release_s=1.5, duration_s=6.0, seed=9)
    _, second = _push_hold_release(release_s=4.0, held_n=3.0, duration_s=6.0, seed=10)
    return t, np.where(t < 2.0, first, 0.0) + np.where(t > 2.5, second, 0.0)


def test_several_pushes_give_the_strongest_or_the_last_before_the_window():
    t, f = _two_pushes()
    strongest = find_excitation(_series(t, f))
    assert abs(strongest.value - 5.0) < 0.1
    assert abs(strongest.time_s - 1.5) < 1e-3
    assert any("other excitation" in note and "4.000 s" in note for note in strongest.notes)
    later = find_excitation(_series(t, f), window_s=(4.1, 5.0))
    assert abs(later.value - 3.0) < 0.06
    assert abs(later.time_s - 4.0) < 1e-3
    earlier = find_excitation(_series(t, f), window_s=(2.0, 3.0))
    assert abs(earlier.time_s - 1.5) < 1e-3
    with pytest.raises(ForceError, match="after the window's end"):
        find_excitation(_series(t, f), window_s=(0.0, 0.5))
    with pytest.raises(ForceError, match="not a time span"):
        find_excitation(_series(t, f), window_s=(3.0, 2.0))


# --- the stated uncertainty ---------------------------------------------------------------------------


def test_the_held_force_uncertainty_covers_the_error_over_50_noise_seeds():
    scores = np.zeros(50)
    for seed in range(50):
        release_s = 2.0 + np.random.default_rng(100 + seed).uniform(0, 0.01)
        t, f = _push_hold_release(release_s=release_s, seed=seed)
        found = find_excitation(_series(t, f))
        scores[seed] = abs(found.value - HELD_N) / found.uncertainty
    assert np.sum(scores > 3) <= 3, np.sort(scores)[-5:]
    assert 0.5 < np.sqrt(np.mean(scores**2)) < 1.5  # neither too small nor inflated


def test_the_impulse_uncertainty_covers_the_error_over_50_noise_seeds():
    scores = np.zeros(50)
    for seed in range(50):
        rate_hz = 500.0 if seed % 2 else 1000.0
        centre_s = 1.23 + np.random.default_rng(200 + seed).uniform(0, 1 / rate_hz)
        t, f, impulse = _strike(rate_hz=rate_hz, centre_s=centre_s, seed=seed)
        found = find_excitation(_series(t, f))
        scores[seed] = abs(found.value - impulse) / found.uncertainty
    assert np.sum(scores > 3) <= 3, np.sort(scores)[-5:]


# --- logs ---------------------------------------------------------------------------------------------


def test_csv_logs_of_both_forms_parse_with_comments_and_the_offset():
    t, f = _push_hold_release(seed=12)
    three = np.column_stack([f, 0.5 * f, np.zeros_like(f)])
    series = read_force_log(_csv(t, three), name="force.csv", offset_s=-0.25)
    assert series.force_n.shape == (t.size, 3)
    assert series.frame_id == "ft_sensor_link"
    np.testing.assert_allclose(series.times_s, t - 0.25, atol=1e-9)
    np.testing.assert_allclose(series.force_n, three, rtol=1e-8, atol=1e-9)
    assert series.source == "log force.csv"
    assert not series.in_camera_frame
    one = read_force_log(_csv(t, f), name="force.csv")
    assert one.force_n.shape == (t.size, 1)
    found = find_excitation(one)
    assert abs(found.value / HELD_N - 1) < 0.02
    assert abs(found.time_s - 2.0) < 1e-3
    shifted = find_excitation(series)
    assert abs(shifted.time_s - 1.75) < 1e-3


def test_csv_with_semicolons_tabs_extra_columns_and_any_case_parses():
    text = "Time_S;FX;FY;FZ;TX\n" + "".join(f"{k * 0.01};{k};0;0;9\n" for k in range(10))
    series = read_force_log(text.encode(), name="wrench.txt")
    np.testing.assert_allclose(series.force_n[:, 0], np.arange(10.0))
    tabbed = "time_s\tforce_n\n" + "".join(f"{k * 0.01}\t{k}\n" for k in range(10))
    assert read_force_log(tabbed.encode(), name="f.tsv").force_n.shape == (10, 1)


def test_json_logs_of_each_form_parse():
    t, f = _push_hold_release(seed=13)
    columns = {"time_s": t.tolist(), "fx": f.tolist(), "fy": (0 * f).tolist(), "fz": (-f).tolist()}
    columns["frame_id"] = "ft_sensor_link"
    from_columns = read_force_log(json.dumps(columns).encode(), name="force.json")
    assert from_columns.force_n.shape == (t.size, 3)
    assert from_columns.frame_id == "ft_sensor_link"
    samples = {"samples": [{"time_s": a, "fx": b, "fy": 0.0, "fz": -b} for a, b in zip(t, f, strict=True)]}
    from_samples = read_force_log(json.dumps(samples).encode(), name="force.json")
    np.testing.assert_array_equal(from_samples.force_n, from_columns.force_n)
    magnitude = {"time_s": t.tolist(), "force_n": f.tolist()}
    sniffed = read_force_log(json.dumps(magnitude).encode(), name="force.log", offset_s=1.0)
    assert sniffed.force_n.shape == (t.size, 1)
    np.testing.assert_allclose(sniffed.times_s, t + 1.0)
    bare = [{"time_s": a, "force_n": b} for a, b in zip(t, f, strict=True)]
    assert read_force_log(json.dumps(bare).encode(), name="force.json").force_n.shape == (t.size, 1)
    found = find_excitation(from_samples)
    assert found.kind == "step_release"
    assert abs(found.value / (HELD_N * math.sqrt(2)) - 1) < 0.02


def _rows(times: list[float], values: list[float]) -> bytes:
    return ("time_s,force_n\n" + "".join(f"{a},{b}\n" for a, b in zip(times, values, strict=True))).encode()


@pytest.mark.parametrize(
    ("data", "name", "expected"),
    [
        (_rows([0, 1, 2, 3, 2.5, 5, 6, 7, 8], [0] * 9), "f.csv", "times run backwards at row 5"),
        (_rows([0, 1, 2, 2, 4, 5, 6, 7, 8], [0] * 9), "f.csv", "times repeat at row 4"),
        (_rows(list(range(9)), [0, 0, float("nan"), 0, 0, 0, 0, 0, 0]), "f.csv", "row 3 is not finite"),
        (_rows(list(range(9)), [0, 0, 0, float("inf"), 0, 0, 0, 0, 0]), "f.csv", "row 4 is not finite"),
        (
            b'{"time_s": [0, 1, 2, 3, 4, 5, 6, 7, 8], "force_n": [0, 0, 0, 0, NaN, 0, 0, 0, 0]}',
            "f.json",
            "row 5",
        ),
        (_rows(list(range(7)), [0] * 7), "f.csv", "has 7 samples, too few"),
        (b"time_s,fx,fy\n0,1,2\n", "f.csv", "lacks the columns it needs (found: fx, fy, time_s)"),
        (b'{"t": [1, 2], "force_n": [1, 2]}', "f.json", "lacks the columns"),
        (b"time_s,force_n\n0,1\n1,x\n", "f.csv", "row 2, column force_n: 'x' is not a number"),
        (b"time_s,force_n\n0,1\n1,2,3\n", "f.csv", "line 3 has 3 fields, the header 2"),
        (b'{"time_s": [0, 1], "force_n": [1]}', "f.json", "differ in length"),
        (b'{"time_s": [0, 1,', "f.json", "is not valid JSON"),
        (b'{"samples": [1, 2, 3]}', "f.json", "samples must be a list of objects"),
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", "f.csv", "not UTF-8 text"),
        (b"  \n", "f.csv", "is empty"),
        (b"# only a comment\n", "f.csv", "has no header"),
    ],
    ids=[
        "backwards",
        "repeated",
        "nan",
        "inf",
        "json-nan",
        "too-few",
        "missing-fz",
        "missing-time",
        "not-a-number",
        "ragged",
        "json-lengths",
        "bad-json",
        "bad-samples",
        "binary",
        "empty",
        "comment-only",
    ],
)
def test_bad_logs_give_a_force_error_naming_the_problem(data, name, expected):
    with pytest.raises(ForceError) as raised:
        read_force_log(data, name=name)
    message = str(raised.value)
    assert expected in message, message
    assert name in message
    if "lacks the columns" in expected:
        assert "time_s,fx,fy,fz" in message
        assert "force_n" in message


def test_force_errors_are_parameter_errors_with_their_own_code():
    assert issubclass(ForceError, ParameterError)
    assert ForceError.code == "invalid-force"


def test_force_series_checks_its_arrays():
    t = np.arange(10, dtype=np.float64) * 0.002
    series = ForceSeries(times_s=t, force_n=np.arange(10.0), source="topic /ft")
    assert series.force_n.shape == (10, 1)
    assert series.force_n.dtype == np.float64
    with pytest.raises(ForceError, match="do not fit"):
        ForceSeries(times_s=t, force_n=np.zeros((10, 2)), source="topic /ft")
    with pytest.raises(ForceError, match="topic /ft: times run backwards at row 3"):
        ForceSeries(times_s=t[[0, 1, 0, 3, 4, 5, 6, 7, 8, 9]], force_n=np.zeros(10), source="topic /ft")
    with pytest.raises(ForceError, match="offset_s"):
        read_force_log(_rows(list(range(9)), [0] * 9), name="f.csv", offset_s=math.nan)
