"""The one progress schedule: phases in order, spans that meet, reports clamped to their phase."""

from __future__ import annotations

import itertools

import pytest

from workers.pipeline.model import PROGRESS_SCHEDULE, report_progress


def test_the_phases_follow_each_other_without_gaps_or_overlaps() -> None:
    order = ["survey", "look", "fine", "spectrum", "segmentation", "mechanics"]
    spans = [PROGRESS_SCHEDULE[p][1:] for p in order]
    assert spans[0][0] == 0.0
    assert spans[-1][1] == 1.0
    for (start, end), (next_start, _) in itertools.pairwise(spans):
        assert start < end <= next_start
        assert next_start - end <= 0.02  # at most a sliver between two phases
    # One flow pass covers what the two passes of the front end cover together.
    assert PROGRESS_SCHEDULE["flow"][1:] == (PROGRESS_SCHEDULE["look"][1], PROGRESS_SCHEDULE["fine"][2])


@pytest.mark.parametrize(("done", "expected"), [(-1.0, 0.5), (0.0, 0.5), (0.5, 0.65), (1.0, 0.8), (3.0, 0.8)])
def test_a_report_lies_within_its_phase(done: float, expected: float) -> None:
    seen: list[tuple[str, float]] = []
    report_progress(lambda stage, fraction: seen.append((stage, fraction)), "fine", done)
    assert seen == [("flow", pytest.approx(expected))]


def test_no_callback_is_fine() -> None:
    report_progress(None, "mechanics", 0.5)
