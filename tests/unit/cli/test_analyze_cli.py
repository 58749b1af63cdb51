"""``eigenscope analyze`` from the outside: a real process, one-line errors, exit codes, result files."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from workers.pipeline.clipio import write_npz


def eigenscope(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "eigenscope", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd,
        check=False,
    )


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli") / "clip.npz"
    done = eigenscope("synth", "--out", out, "--frames", 64, "--width", 320, "--height", 240, "--seed", 3)
    assert done.returncode == 0, done.stderr
    return out


@pytest.mark.accuracy  # a whole analysis
def test_analyze_writes_result_and_mask_and_prints_a_summary(clip, tmp_path):
    done = eigenscope("analyze", clip, "--force-n", 10, "--out", tmp_path / "out")
    assert done.returncode == 0, done.stderr
    assert "object 1: f = " in done.stdout
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    truth = json.loads(clip.with_name("clip.truth.json").read_text())["objects"][0]
    assert result["eigenfrequency_hz"] == pytest.approx(truth["eigenfrequency_hz"], rel=0.01)
    assert result["objects"][0]["mass_kg"] == pytest.approx(truth["mass_kg"], rel=0.1)
    assert (tmp_path / "out" / result["artifacts"]["mask"]).is_file()
    assert result["parameters"]["excitation"][0]["force_n"] == 10


@pytest.mark.accuracy  # a whole analysis
def test_point_excitation_names_the_object(clip, tmp_path):
    done = eigenscope(
        "analyze", clip, "--force-n", 10, "--point", 160, 120, "--out", tmp_path / "o", "--json"
    )
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout)["objects"][0]["stiffness_n_per_m"] is not None


@pytest.mark.accuracy  # whole analyses
@pytest.mark.parametrize("threads", [1, 3])
def test_flow_threads_are_the_users_choice_and_give_the_same_result(clip, tmp_path, threads):
    """One thread runs the flow a pair at a time (as the paper's recipe did); the result is the same as
    with the default two, bit for bit, and the output is complete."""
    runs = {}
    for name, extra in (("default", []), ("chosen", ["--flow-threads", threads])):
        done = eigenscope("analyze", clip, "--force-n", 10, *extra, "--out", tmp_path / name, "--json")
        assert done.returncode == 0, done.stderr
        runs[name] = json.loads(done.stdout)
        assert json.loads((tmp_path / name / "result.json").read_text()) == runs[name]
    assert runs["default"]["parameters"]["flow_threads"] == 2
    assert runs["chosen"]["parameters"]["flow_threads"] == threads
    for key in ("eigenfrequency_hz", "stiffness_n_per_m", "mass_kg", "damping_ratio"):
        assert runs["chosen"]["objects"][0][key] == runs["default"]["objects"][0][key], key


@pytest.mark.parametrize(
    ("make", "args", "expected"),
    [
        ("missing", [], "No such file"),
        ("text", [], "not a"),
        ("few-frames", [], "frames"),
        ("no-rgb", [], "missing key 'rgb'"),
        ("ok", ["--fps", "-3"], "--fps"),
        ("ok", ["--force-n", "10", "--point", "1", "1"], "matches no object"),
        ("ok", ["--frames", "4"], "frames"),
        ("ok", ["--flow-threads", "0"], "--flow-threads"),
    ],
)
def test_bad_input_gets_one_line_and_exit_2(make, args, expected, clip, tmp_path):
    path = tmp_path / "bad.npz"
    if make == "text":
        path.write_text("not a clip\n")
    elif make == "few-frames":
        write_npz(path, np.zeros((3, 32, 32, 3), np.uint8), fps=30)
    elif make == "no-rgb":
        np.savez(path, colour=np.zeros((10, 32, 32, 3), np.uint8), fps=30.0)
    elif make == "ok":
        path = clip
    done = eigenscope("analyze", path, *args, "--out", tmp_path / "out")
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert expected.lower() in lines[0].lower()


@pytest.mark.accuracy  # a whole analysis
def test_analyze_writes_every_image(clip, tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "eigenscope", "analyze", str(clip), "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,  # a guard against a hang, not a bound on the time
    )
    assert done.returncode == 0, done.stderr
    assert len(list((tmp_path / "out").glob("*.png"))) == 6
