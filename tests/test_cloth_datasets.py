"""Expert demonstrations written as both datasets, read back through LeRobotDataset."""

from __future__ import annotations

import json

import numpy as np
import pytest
from lerobot.datasets.lerobot_dataset import LeRobotDataset

from lerobot_taxdpd.data.schema import (
    ACTION_KEY,
    DONE_KEY,
    GOAL_CLOUD_KEY,
    OBJECT_KEY,
    SCENE_KEY,
    STATE_KEY,
    SUCCESS_KEY,
)
from lerobot_taxdpd.sim.cli import main
from lerobot_taxdpd.sim.cloth.env import SimSettings


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    root = tmp_path_factory.mktemp("cloth") / "demos"
    argv = ["generate", "--task", "cloth_hang", "--episodes", "2", "--seed", "3", "--frames-per-episode", "3"]
    assert main([*argv, "--repo-id", "local/cloth_hang", "--root", str(root)]) == 0
    goal = LeRobotDataset("local/cloth_hang_goal", root=root / "goal")
    policy = LeRobotDataset("local/cloth_hang_policy", root=root / "policy")
    return root, goal, policy


def test_goal_dataset_round_trips(datasets):
    _, goal, policy = datasets
    assert goal.meta.total_episodes == 2 and goal.meta.total_frames == 6
    frame = goal[0]
    for key in (OBJECT_KEY, SCENE_KEY, ACTION_KEY):
        assert tuple(frame[key].shape) == (512, 3)
    # Views of one demo sample different surface points of the same cloth: same size, different rows.
    a, b = goal[0], goal[1]
    assert not np.allclose(a[OBJECT_KEY].numpy(), b[OBJECT_KEY].numpy())
    spread = lambda cloud: np.linalg.norm(cloud - cloud.mean(0), axis=1).mean()  # noqa: E731
    assert spread(a[OBJECT_KEY].numpy()) == pytest.approx(spread(b[OBJECT_KEY].numpy()), rel=0.1)
    # The goal is the settled cloth: the same material points, moved towards the hangers and hanging lower.
    moved = np.linalg.norm(a[ACTION_KEY].numpy() - a[OBJECT_KEY].numpy(), axis=1)
    assert moved.min() > 0.5
    # The policy dataset's goal cloud is the same settled cloth as the goal dataset's.
    last = policy[policy.meta.total_frames // 2 - 1]
    assert np.abs(last[GOAL_CLOUD_KEY].numpy()[:, 2].mean() - a[ACTION_KEY].numpy()[:, 2].mean()) < 0.05


def test_policy_dataset_round_trips(datasets):
    root, _, policy = datasets
    steps = SimSettings().max_episode_steps
    assert policy.meta.total_episodes == 2 and policy.meta.total_frames == 2 * steps
    assert policy.fps == round(1 / SimSettings().control_period)
    frames = [policy[i] for i in range(steps)]
    states = np.stack([f[STATE_KEY].numpy() for f in frames])
    actions = np.stack([f[ACTION_KEY].numpy() for f in frames])
    # Actions are the executed gripper displacements: positions advance by exactly the recorded action.
    np.testing.assert_allclose(states[1:, :6] - states[:-1, :6], actions[:-1], atol=1e-5)
    np.testing.assert_allclose(states[1:, 6:], actions[:-1] / SimSettings().control_period, rtol=1e-4, atol=1e-4)
    goals = np.stack([f[GOAL_CLOUD_KEY].numpy() for f in frames])
    assert np.ptp(goals, axis=0).max() == 0.0, "one goal per rollout"
    done = [bool(f[DONE_KEY]) for f in frames]
    assert done == [False] * (steps - 1) + [True]
    assert bool(frames[-1][SUCCESS_KEY])
    info = json.loads((root / "policy" / "meta" / "info.json").read_text())
    assert info["features"][GOAL_CLOUD_KEY]["shape"] == [512, 3]
    assert (root / "policy" / "README.md").is_file()


def test_generate_refuses_to_overwrite_and_bad_arguments(datasets, tmp_path, capsys):
    root, _, _ = datasets
    argv = ["generate", "--task", "cloth_hang", "--repo-id", "local/x"]
    for options, message in [
        (["--episodes", "1", "--root", str(root), "--dataset", "both"], "already exists"),
        (["--episodes", "0", "--root", str(tmp_path / "new")], "episodes"),
        (["--episodes", "1", "--frames-per-episode", "1", "--root", str(tmp_path / "new")], "--frames-per-episode"),
        (["--episodes", "1", "--views", "1", "--root", str(tmp_path / "new")], "--views is deprecated"),
    ]:
        assert main([*argv, *options]) == 1
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*argv, "--episodes", "1", "--root", str(tmp_path / "new"), "--task", "mug_rack"])
    assert not (tmp_path / "new").exists()


def test_the_viewer_shows_a_policy_episode_with_its_grippers_and_numbers(datasets, tmp_path):
    import rerun.dataframe as rrd

    from lerobot_taxdpd.viewer import main as viewer

    root, _, policy = datasets
    recording = tmp_path / "policy.rrd"
    assert viewer(["dataset", "--root", str(root / "policy"), "--episode", "0", "--save", str(recording)]) == 0
    entities = {column.entity_path for column in rrd.load_recording(recording).schema().component_columns()}
    assert {f"/{OBJECT_KEY}", f"/{SCENE_KEY}", f"/{GOAL_CLOUD_KEY}", "/grippers"} <= entities
    assert {f"/plots/{STATE_KEY}/11", f"/plots/{ACTION_KEY}/5"} <= entities
