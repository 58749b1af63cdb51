"""``eigenscope analyze`` from the outside, analysing a clip: the result files, the summary it prints, the
images, and the same figures whatever the number of flow threads (its bad input is in
``tests/unit/cli/test_analyze_cli.py``)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def test_analyze_writes_result_and_mask_and_prints_a_summary(cli_clip, run_eigenscope, tmp_path):
    done = run_eigenscope("analyze", cli_clip, "--force-n", 10, "--out", tmp_path / "out")
    assert done.returncode == 0, done.stderr
    assert "object 1: f = " in done.stdout
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    truth = json.loads(cli_clip.with_name("clip.truth.json").read_text())["objects"][0]
    assert result["eigenfrequency_hz"] == pytest.approx(truth["eigenfrequency_hz"], rel=0.01)
    assert result["objects"][0]["mass_kg"] == pytest.approx(truth["mass_kg"], rel=0.1)
    assert (tmp_path / "out" / result["artifacts"]["mask"]).is_file()
    assert result["parameters"]["excitation"][0]["force_n"] == 10


def test_point_excitation_names_the_object(cli_clip, run_eigenscope, tmp_path):
    done = run_eigenscope(
        "analyze", cli_clip, "--force-n", 10, "--point", 160, 120, "--out", tmp_path / "o", "--json"
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["objects"][0]["stiffness_n_per_m"] is not None


@pytest.mark.parametrize("threads", [1, 3])
def test_flow_threads_are_the_users_choice_and_give_the_same_result(
    cli_clip, run_eigenscope, tmp_path, threads
):
    """One thread runs the flow a pair at a time (as the paper's recipe did); the result is the same as
    with the default two, bit for bit, and the output is complete."""
    runs = {}
    for name, extra in (("default", []), ("chosen", ["--flow-threads", threads])):
        done = run_eigenscope(
            "analyze", cli_clip, "--force-n", 10, *extra, "--out", tmp_path / name, "--json"
        )
        assert done.returncode == 0, done.stderr
        runs[name] = json.loads(done.stdout)
        assert json.loads((tmp_path / name / "result.json").read_text()) == runs[name]
    assert runs["default"]["parameters"]["flow_threads"] == 2
    assert runs["chosen"]["parameters"]["flow_threads"] == threads
    for key in ("eigenfrequency_hz", "stiffness_n_per_m", "mass_kg", "damping_ratio"):
        assert runs["chosen"]["objects"][0][key] == runs["default"]["objects"][0][key], key


def test_analyze_writes_every_image(cli_clip, tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "eigenscope", "analyze", str(cli_clip), "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,  # a guard against a hang, not a bound on the time
    )
    assert done.returncode == 0, done.stderr
    from workers.pipeline.figures import ARTIFACT_FILES

    pngs = {name for name in ARTIFACT_FILES.values() if name.endswith(".png")}
    assert {p.name for p in (tmp_path / "out").glob("*.png")} == pngs  # the mask, the figures and modes.png
