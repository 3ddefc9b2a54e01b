"""The scripted expert hangs the cloth on the hole and hanger it is asked for."""

from __future__ import annotations

import numpy as np
import pytest

from lerobot_taxdpd.data.schema import STATE_KEY
from lerobot_taxdpd.sim.cloth.env import ClothHangEnv
from lerobot_taxdpd.sim.cloth.expert import ScriptedExpert
from lerobot_taxdpd.sim.cloth.rollout import demo_target, expert, rollout
from lerobot_taxdpd.sim.cloth.scene import sample_scene


@pytest.fixture(scope="module")
def env():
    environment = ClothHangEnv(split="train")
    yield environment
    environment.close()


@pytest.mark.parametrize(("split", "seed", "hole", "hanger"), [("train", 3, 1, 0), ("test", 4, 1, 1)])
def test_expert_hangs_the_requested_hole_on_the_requested_hanger(env, split, seed, hole, hanger):
    scene = sample_scene(split, seed)
    assert len(scene.holes) == 2, "pick a two-hole scene so the target is not the only choice"
    episode = rollout(env, scene, expert(hole, hanger), record=True)
    assert episode.success
    expected = np.zeros((2, 2), dtype=bool)
    expected[hole, hanger] = True
    np.testing.assert_array_equal(episode.success_matrix, expected)
    assert len(episode.actions) == env.settings.max_episode_steps
    # The settled cloth hangs from the chosen peg: its hole is near the peg, well below where it started.
    centroid = episode.final_vertices[env.mesh.hole_loops[hole]].mean(axis=0)
    peg = scene.hangers[hanger]
    assert np.linalg.norm(centroid - peg.goal_point) < 1.0
    assert episode.seconds < 20.0


def test_expert_rejects_indices_outside_the_scene(env):
    env.reset(seed=0)
    with pytest.raises(ValueError, match="hole"):
        ScriptedExpert(env, hole=5, hanger=0)
    with pytest.raises(ValueError, match="hanger"):
        ScriptedExpert(env, hole=0, hanger=2)


@pytest.mark.slow
@pytest.mark.parametrize("split", ["train", "test"])
def test_expert_succeeds_on_at_least_90_percent_of_scenes(env, split):
    """The issue's bar for the demonstrator, on 20 fresh scenes per split (about 2 minutes each)."""
    successes = 0
    for seed in range(500, 520):
        scene = sample_scene(split, seed)
        successes += rollout(env, scene, expert(*demo_target(scene))).success
    assert successes >= 18, f"{successes}/20 on {split} geometry"


def test_dart_noise_perturbs_the_rollout_but_records_the_experts_own_corrections(env):
    """With --action-noise the expert still hangs the cloth from where the noise pushed it, and the
    dataset's action is what the expert asked for there, not the noisy displacement that was executed."""
    scene = sample_scene("train", 3)
    clean = rollout(env, scene, expert(1, 0), record=True)
    noisy = rollout(env, scene, expert(1, 0), record=True, action_noise=0.02, noise_rng=np.random.default_rng(0))
    assert noisy.success
    states = np.stack([o[STATE_KEY] for o in noisy.observations])
    executed = states[1:, :6] - states[:-1, :6]  # gripper displacement between observations
    recorded = np.stack(noisy.actions)[:-1]
    assert np.abs(executed - recorded).mean() > 0.01  # about the noise's 0.02 m std
    assert np.abs(np.stack(clean.actions) - np.stack(noisy.actions)).mean() > 1e-3  # other states, other labels
    replay = rollout(env, scene, expert(1, 0), record=True, action_noise=0.02, noise_rng=np.random.default_rng(0))
    np.testing.assert_allclose(np.stack(replay.actions), np.stack(noisy.actions), atol=1e-6)
    with pytest.raises(ValueError, match="noise_rng"):
        rollout(env, scene, expert(1, 0), action_noise=0.02)
