"""`gc_dp3` through LeRobot's own `lerobot-train`: it learns a goal-conditioned action, then fine-tunes and
resumes with its clouds in the frame of the first run.

The tiny dataset has the gc_dp3 schema and one twist: the action depends only on the goal cloud (move
towards the hanger the goal hangs on), so a policy that ignores its goal input cannot pass the bound.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies.factory import make_pre_post_processors

from conftest import TINY_GC_DP3 as TINY
from lerobot_taxdpd.data.dataset_writer import DatasetCardInfo, DatasetWriter
from lerobot_taxdpd.data.schema import (
    ACTION_KEY,
    DONE_KEY,
    GOAL_CLOUD_KEY,
    OBJECT_KEY,
    SCENE_KEY,
    STATE_KEY,
    SUCCESS_KEY,
    cloth_policy_features,
)
from lerobot_taxdpd.policies.gc_dp3.modeling_gc_dp3 import GcDp3Policy

POINTS = 32
FRAMES = 12
SPEED = 0.05  # metres per step towards the goal's hanger
def write_goal_side_dataset(root, episodes: int = 4):
    """Hangers at x = -2 and x = +2; each episode's goal hangs the cloth on one of them (alternating).

    Cloth, grippers and velocities are drawn afresh every frame, independently of the side, so the goal
    cloud is the only input that tells which way to move.
    """
    rng = np.random.default_rng(0)
    hangers = np.concatenate(
        [rng.normal([-2.0, 0.0, 4.0], 0.2, (POINTS // 2, 3)), rng.normal([2.0, 0.0, 4.0], 0.2, (POINTS // 2, 3))]
    )
    card = DatasetCardInfo(source="synthetic test data", source_license="apache-2.0")
    features = cloth_policy_features(POINTS, POINTS)
    with DatasetWriter("local/goal_side", root, features, fps=20, card=card) as writer:
        for episode in range(episodes):
            side = 1.0 if episode % 2 else -1.0
            goal = rng.normal([2.0 * side, 0.0, 4.2], 0.4, (POINTS, 3))
            action = np.array([SPEED * side, 0.0, 0.0] * 2)
            frames = []
            for t in range(FRAMES):
                grippers = np.array([[-0.5, 0.0, 6.0], [0.5, 0.0, 6.0]]) + rng.normal(0.0, 0.1, (2, 3))
                state = np.concatenate([grippers.reshape(6), rng.normal(0.0, 0.5, 6)])
                frames.append(
                    {
                        OBJECT_KEY: rng.normal([0.0, 0.0, 5.0], 0.4, (POINTS, 3)).astype(np.float32),
                        SCENE_KEY: hangers.astype(np.float32),
                        GOAL_CLOUD_KEY: goal.astype(np.float32),
                        STATE_KEY: state.astype(np.float32),
                        ACTION_KEY: action.astype(np.float32),
                        DONE_KEY: np.array([t == FRAMES - 1]),
                        SUCCESS_KEY: np.array([t == FRAMES - 1]),
                    }
                )
            writer.add_episode(frames, task="move towards the goal's hanger")
    return root


def train(cli, dataset, output_dir, *args, steps, batch_size=8):
    return cli(
        "lerobot-train",
        "--dataset.repo_id=local/goal_side",
        f"--dataset.root={dataset}",
        "--policy.push_to_hub=false",
        f"--batch_size={batch_size}",
        f"--steps={steps}",
        f"--save_freq={steps}",
        "--log_freq=50",
        "--num_workers=0",
        "--seed=0",
        f"--output_dir={output_dir}",
        *args,
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return write_goal_side_dataset(tmp_path_factory.mktemp("gc_dp3") / "goal_side")


def saved_processors(checkpoint):
    """A checkpoint's pre- and postprocessor, built as `lerobot-eval` builds them."""
    config = PreTrainedConfig.from_pretrained(checkpoint)
    return make_pre_post_processors(
        config, pretrained_path=str(checkpoint), preprocessor_overrides={"device_processor": {"device": "cpu"}}
    )


def first_actions(checkpoint, dataset_root, swap_goals: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Predicted and recorded first action of every frame, inference built as lerobot-eval builds it.

    With `swap_goals`, every frame gets the goal of the next episode (the other hanger)."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    policy = GcDp3Policy.from_pretrained(checkpoint).eval()
    preprocessor, postprocessor = saved_processors(checkpoint)
    data = LeRobotDataset("local/goal_side", root=dataset_root)
    predicted, recorded = [], []
    generator = torch.Generator().manual_seed(0)
    for index in range(len(data)):
        frame = data[index]
        observation = {key: frame[key] for key in (OBJECT_KEY, SCENE_KEY, GOAL_CLOUD_KEY, STATE_KEY)}
        if swap_goals:
            observation[GOAL_CLOUD_KEY] = data[(index + FRAMES) % len(data)][GOAL_CLOUD_KEY]
        policy.reset()
        observation = preprocessor(observation)
        chunk = policy.predict_action_chunk(observation, generator=generator)
        predicted.append(postprocessor(chunk[:, 0]).reshape(-1).numpy())
        recorded.append(frame[ACTION_KEY].numpy())
    return np.stack(predicted), np.stack(recorded)


def assert_clouds_keep_the_first_runs_frame(checkpoint, dataset_root, frame_of_first_run):
    """The checkpoint's preprocessor, as `lerobot-eval` builds it, min-max normalises the state only, and the
    policy keeps the isotropic cloud frame the first run derived from the dataset."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    preprocessor, _ = saved_processors(checkpoint)
    frame = LeRobotDataset("local/goal_side", root=dataset_root)[0]
    processed = preprocessor({key: frame[key] for key in (OBJECT_KEY, SCENE_KEY, GOAL_CLOUD_KEY, STATE_KEY)})
    for key in (OBJECT_KEY, SCENE_KEY, GOAL_CLOUD_KEY):
        torch.testing.assert_close(processed[key][0], frame[key], msg=f"{checkpoint}: {key} was rescaled")
    assert processed[STATE_KEY].abs().max() <= 1.0 < frame[STATE_KEY].abs().max(), "state is mapped to [-1, 1]"
    saved = json.loads((checkpoint / "config.json").read_text())
    assert (saved["cloud_normalization"], saved["cloud_center"], saved["cloud_scale"]) == frame_of_first_run


def test_gc_dp3_learns_the_goal_conditioned_action_and_fine_tunes(cli, dataset, tmp_path, monkeypatch):
    # One torch thread: on a small shared CPU, two threads of tiny ops spin against each other (10x slower).
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    result = train(cli, dataset, tmp_path / "run", *TINY, steps=200)
    assert "loss:" in result.stdout + result.stderr
    checkpoint = tmp_path / "run" / "checkpoints" / "last" / "pretrained_model"
    saved = json.loads((checkpoint / "config.json").read_text())
    assert saved["type"] == "gc_dp3" and saved["horizon"] == 4 and saved["n_obs_steps"] == 2
    frame_of_first_run = ("isotropic", saved["cloud_center"], saved["cloud_scale"])
    assert len(saved["cloud_center"]) == 3 and saved["cloud_scale"] > 0, "derived from the dataset's stats"

    predicted, recorded = first_actions(checkpoint, dataset)
    # Ignoring the goal, the best guess for the grippers' x motion is 0: error SPEED on every frame.
    error = np.abs(predicted - recorded)[:, [0, 3]].mean()
    assert error < 0.2 * SPEED, f"mean x-action error {error:.4f} m (bound {0.2 * SPEED} m)"
    assert np.abs(predicted - recorded)[:, [1, 2, 4, 5]].mean() < 0.2 * SPEED
    # The goal decides: given the other episode's goal, the policy moves the other way.
    swapped, _ = first_actions(checkpoint, dataset, swap_goals=True)
    np.testing.assert_array_equal(np.sign(swapped[:, [0, 3]]), -np.sign(recorded[:, [0, 3]]))

    # Fine-tuning goes through lerobot's override path (device/rename/normalizer steps by registry name).
    train(cli, dataset, tmp_path / "finetune", f"--policy.path={checkpoint}", steps=2, batch_size=4)
    tuned = tmp_path / "finetune" / "checkpoints" / "last" / "pretrained_model"
    before, after = GcDp3Policy.from_pretrained(checkpoint), GcDp3Policy.from_pretrained(tuned)
    assert any(not torch.equal(a, b) for a, b in zip(before.parameters(), after.parameters(), strict=True))

    # Starting from a checkpoint, LeRobot's trainer rebuilds the normaliser with every input feature; the
    # clouds must still enter as in the first run, whether fine-tuned or resumed.
    cli("lerobot-train", "--resume=true", "--steps=202", f"--config_path={checkpoint}/train_config.json")
    first, resumed = (tmp_path / "run" / "checkpoints" / step / "pretrained_model" for step in ("000200", "000202"))
    for saved_checkpoint in (first, tuned, resumed):
        assert_clouds_keep_the_first_runs_frame(saved_checkpoint, dataset, frame_of_first_run)
