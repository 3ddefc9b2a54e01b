"""`python -m lerobot_taxdpd.sim generate` writes LeRobot v3.0 datasets that LeRobot itself reads back."""

from __future__ import annotations

import json

import pytest
import torch

from conftest import run_cli
from lerobot_taxdpd.data.point_order import read_point_order
from lerobot_taxdpd.data.schema import ACTION_KEY, DEFAULT_POINT_COUNTS, GOAL_TRANSFORM_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.sim.cli import main
from lerobot_taxdpd.sim.generate import generate_dataset
from lerobot_taxdpd.sim.tasks import get_task


def _frames(root, repo_id):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    dataset = LeRobotDataset(repo_id, root=root)
    return dataset, [dataset[i] for i in range(len(dataset))]


def test_generated_demos_round_trip_through_lerobot(tmp_path):
    root = tmp_path / "waterproof"
    run_cli(
        "python",
        "-m",
        "lerobot_taxdpd.sim",
        "generate",
        "--task",
        "insert_waterproof",
        "--episodes",
        "2",
        "--split",
        "train",
        "--repo-id",
        "local/waterproof",
        "--root",
        str(root),
        "--seed",
        "7",
    )
    dataset, frames = _frames(root, "local/waterproof")
    num_object, num_scene = DEFAULT_POINT_COUNTS["nist"]
    assert dataset.num_episodes == 2 and len(frames) == 4
    for frame in frames:
        assert frame[OBJECT_KEY].shape == (num_object, 3) and frame[SCENE_KEY].shape == (num_scene, 3)
        goal = frame[OBJECT_KEY] @ frame[GOAL_TRANSFORM_KEY][:3, :3].T + frame[GOAL_TRANSFORM_KEY][:3, 3]
        torch.testing.assert_close(goal, frame[ACTION_KEY], atol=1e-5, rtol=0)
        assert frame["task"] == get_task("insert_waterproof").description
    # The two frames of an episode are two observations of one demonstration.
    first, second = frames[0], frames[1]
    assert first["episode_index"] == second["episode_index"]
    torch.testing.assert_close(first[GOAL_TRANSFORM_KEY], second[GOAL_TRANSFORM_KEY])
    assert not torch.equal(first[OBJECT_KEY], second[OBJECT_KEY])
    card = json.loads((root / "meta" / "taxdpd_card.json").read_text())["card"]
    assert card["details"]["geometry split"] == "train" and card["details"]["scene seeds"] == "7..8"
    assert "--seed 7" in card["command"]
    # The task reduces its renders by FPS, so the step may take the encoders' layouts as prefixes.
    assert read_point_order(root) == {OBJECT_KEY: True, SCENE_KEY: True}

    # Same seed, same data: the dataset is reproducible.
    again = generate_dataset(
        get_task("insert_waterproof"),
        episodes=2,
        split="train",
        repo_id="local/again",
        root=tmp_path / "again",
        seed=7,
        progress=False,
    )
    _, frames_again = _frames(again, "local/again")
    for a, b in zip(frames, frames_again, strict=True):
        torch.testing.assert_close(a[OBJECT_KEY], b[OBJECT_KEY], atol=0, rtol=0)
        torch.testing.assert_close(a[ACTION_KEY], b[ACTION_KEY], atol=0, rtol=0)


def test_an_existing_dataset_is_never_clobbered_and_bad_arguments_are_named(tmp_path, capsys):
    root = tmp_path / "taken"
    root.mkdir()
    (root / "keep.txt").write_text("precious")
    args = ["generate", "--task", "insert_ssd", "--episodes", "1", "--repo-id", "local/x", "--root", str(root)]
    assert main(args) == 1
    assert "already exists" in capsys.readouterr().err
    assert (root / "keep.txt").read_text() == "precious" and len(list(root.iterdir())) == 1
    with pytest.raises(ValueError, match="--frames-per-episode"):
        generate_dataset(
            get_task("insert_ssd"), episodes=1, split="train", repo_id="x/y", root=tmp_path / "a", frames_per_episode=1
        )
    with pytest.raises(ValueError, match="--episodes"):
        generate_dataset(get_task("insert_ssd"), episodes=0, split="train", repo_id="x/y", root=tmp_path / "b")
    with pytest.raises(ValueError, match="split"):
        generate_dataset(get_task("insert_ssd"), episodes=1, split="holdout", repo_id="x/y", root=tmp_path / "c")
    assert not any(p.name.startswith(("a", "b", "c", ".a", ".b", ".c")) for p in tmp_path.iterdir())
