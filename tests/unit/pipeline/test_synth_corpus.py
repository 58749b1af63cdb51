"""The null corpus's scenes (``workers.pipeline.synth_corpus.still_corpus``): round 0 is the corpus the
accuracy tier tests; every further round (``bench/null_corpus.py --rounds``) is the same scenes with seeds
of their own, so that more clips measure the false-alarm rate instead of the same clips again."""

from __future__ import annotations

from dataclasses import replace

from workers.pipeline.synth_corpus import still_corpus


def test_round_zero_is_the_tested_corpus_and_later_rounds_draw_new_seeds() -> None:
    first = list(still_corpus())
    second = list(still_corpus(round_index=1))
    assert [s.scene.seed for s in first] == list(range(100, 100 + len(first)))
    assert not any(s.name.endswith("-r1") for s in first)
    assert len(second) == len(first) == 12
    seeds = {s.scene.seed for s in first} | {s.scene.seed for s in second}
    assert len(seeds) == 24
    for a, b in zip(first, second, strict=True):
        # The same scene and codec, other noise.
        assert b.name == f"{a.name}-r1"
        assert (a.codec, a.bit_rate, a.keyframe_every) == (b.codec, b.bit_rate, b.keyframe_every)
        assert replace(b.scene, seed=a.scene.seed) == a.scene
