"""Which sampled goal is executed: the first, or the one the samples agree on."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_taxdpd.maths.selection import consensus_index, executed_first


def _samples(rng, right: int, wrong: int, spread: float = 0.005) -> np.ndarray:
    """`right` samples within `spread` of one goal cloud; `wrong` ones each moved away in its own direction."""
    goal = rng.normal(size=(64, 3)) * 0.05
    near = [goal + rng.normal(size=goal.shape) * spread for _ in range(right)]
    far = [goal + rng.normal(size=3) * 0.2 for _ in range(wrong)]
    return np.stack(far + near)  # the wrong ones first, as a blind pick would meet them


def test_consensus_executes_a_sample_the_others_agree_with():
    rng = np.random.default_rng(0)
    samples = _samples(rng, right=4, wrong=6)  # a minority is right, but only the right ones agree
    reordered, index = executed_first(samples, "consensus", radius=0.02)
    assert index >= 6, "the wrong samples scatter; the executed one must come from the agreeing four"
    np.testing.assert_array_equal(reordered[0], samples[index])
    others = [i for i in range(len(samples)) if i != index]
    np.testing.assert_array_equal(reordered[1:], samples[others])  # the rest keep their order
    assert executed_first(samples, "first", radius=0.02)[1] == 0


def test_ties_go_to_the_sample_nearest_the_others():
    line = np.zeros((5, 8, 3))
    line[:, :, 0] = np.arange(5)[:, None] * 0.01  # five clouds in a row: all within the radius of each other
    assert consensus_index(line, radius=1.0) == 2  # the middle one, the medoid
    assert consensus_index(line[:1], radius=1.0) == 0


def test_bad_rules_and_shapes_are_named():
    samples = np.zeros((3, 8, 3))
    with pytest.raises(ValueError, match="goal selection: expected one of first, consensus"):
        executed_first(samples, "best", radius=0.02)
    with pytest.raises(ValueError, match="samples: expected"):
        consensus_index(samples[0], radius=0.02)
    with pytest.raises(ValueError, match="radius: must be positive"):
        consensus_index(samples, radius=0.0)
