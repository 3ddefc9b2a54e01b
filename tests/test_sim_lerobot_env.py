"""The benchmarks as LeRobot envs: `--env.type=taxdpd_sim --env.task=<task>`, through LeRobot's own env
factory, observation preprocessing and the taxdpd processor step that unpacks the clouds."""

from __future__ import annotations

import json

import gymnasium as gym
import imageio
import numpy as np
import pytest
import torch
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.envs.factory import make_env
from lerobot.envs.utils import env_to_policy_features, preprocess_observation
from lerobot.utils.constants import ACTION, OBS_ENV_STATE

import lerobot_taxdpd  # noqa: F401  (registers the env type and the gymnasium ids)
from conftest import run_cli
from lerobot_taxdpd.data.schema import OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.policies.point_cloud_steps import UnpackEnvironmentPointCloudsStep
from lerobot_taxdpd.sim.env_config import TASK_POINT_COUNTS, TaxDPDSimEnvConfig
from lerobot_taxdpd.sim.tasks import get_task, task_names
from lerobot_taxdpd.sim.trials import make_trial


def test_every_task_is_registered_with_its_point_counts():
    assert sorted(TASK_POINT_COUNTS) == sorted(task_names())
    for name in task_names():
        config = EnvConfig.get_choice_class("taxdpd_sim")(task=name)
        num_object, num_scene = get_task(name).num_points
        assert config.features[ACTION].shape == (num_object, 3)
        assert config.features["environment_state"].shape == (num_object + num_scene, 3)
        assert f"lerobot_taxdpd/{name}-v0" in gym.registry
    with pytest.raises(ValueError, match="env.task: unknown task 'cloth'"):
        TaxDPDSimEnvConfig(task="cloth")


def test_a_denser_scene_reaches_the_policy_through_lerobots_factory():
    """`--env.scene_cloud_size` observes as many scene points as a predictor trained on denser demos expects."""
    config = TaxDPDSimEnvConfig(task="insert_ssd", scene_cloud_size=2048)
    assert config.features["environment_state"].shape == (512 + 2048, 3)
    vector = make_env(config, n_envs=1)["taxdpd_sim"][0]
    observation, _ = vector.reset(seed=[3])
    trial = make_trial(get_task("insert_ssd").with_scene_cloud_size(2048), 3, "test")
    np.testing.assert_array_equal(
        observation["environment_state"][0], np.concatenate([trial.object_points, trial.scene_points])
    )
    vector.close()


def test_an_episode_executes_the_goal_cloud_then_shows_it():
    env = gym.make("lerobot_taxdpd/insert_ssd-v0")
    observation, info = env.reset(seed=4)
    trial = make_trial(get_task("insert_ssd"), 4, "test")
    packed = observation["environment_state"]
    np.testing.assert_array_equal(packed, np.concatenate([trial.object_points, trial.scene_points]))
    assert env.observation_space.contains(observation)
    start = env.unwrapped.render()
    _, reward, terminated, _, info = env.step(trial.goal_points().reshape(-1))  # flattened, as lerobot-eval sends it
    assert (reward, terminated, info["is_success"]) == (1.0, False, True)
    placed = env.unwrapped.render()
    assert np.abs(placed.astype(int) - start).max() > 0, "the frame after the placement shows the object moved"
    _, reward, terminated, _, info = env.step(np.zeros(trial.object_points.size))  # its action is ignored
    assert (reward, terminated, info["is_success"]) == (0.0, True, True)
    env.reset(seed=4)
    _, reward, _, _, info = env.step(trial.goal_points() + np.array([0.004, 0.0, 0.0], dtype=np.float32))
    assert reward == 0.0 and not info["is_success"] and "not in a socket" in info["failure"]
    frame = env.unwrapped.render()
    assert frame.shape == (240, 320, 3) and frame.dtype == np.uint8 and frame.std() > 0
    env.reset(seed=4)
    with pytest.raises(ValueError, match="action: expected the goal cloud"):
        env.unwrapped.step(np.zeros((10, 3)))
    env.close()


def test_lerobot_factory_and_preprocessing_hand_the_policy_both_clouds():
    config = TaxDPDSimEnvConfig(task="mug_easyrack")
    features = env_to_policy_features(config)
    assert features[ACTION].type is FeatureType.ACTION and features[OBS_ENV_STATE].type is FeatureType.ENV
    vector = make_env(config, n_envs=2)["taxdpd_sim"][0]
    observation, _ = vector.reset(seed=[11, 12])
    assert vector.call("_max_episode_steps") == (2, 2)
    batch = preprocess_observation(observation)
    num_object = config.features[ACTION].shape[0]
    unpacked = UnpackEnvironmentPointCloudsStep(num_object_points=num_object).observation(batch)
    for env_index, seed in enumerate((11, 12)):
        trial = make_trial(get_task("mug_easyrack"), seed, "test")
        torch.testing.assert_close(unpacked[OBJECT_KEY][env_index], torch.from_numpy(trial.object_points))
        torch.testing.assert_close(unpacked[SCENE_KEY][env_index], torch.from_numpy(trial.scene_points))
    goals = np.stack([env.unwrapped._trial.goal_points().reshape(-1) for env in vector.envs])
    goals[1] += 0.05  # 5 cm off in x, y and z: misses the peg
    _, _, terminated, _, info = vector.step(goals)
    assert not terminated.any() and info["is_success"].tolist() == [True, False]
    _, _, terminated, _, info = vector.step(goals)
    assert terminated.all() and info["final_info"]["is_success"].tolist() == [True, False]
    vector.close()


def test_lerobot_eval_runs_a_taxdpd_checkpoint_on_a_benchmark(tmp_path):
    from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy, make_taxdpd_pre_post_processors

    num_object, num_scene = get_task("insert_ssd").num_points
    config = TaxDPDConfig(
        device="cpu",
        push_to_hub=False,
        point_scale=30.0,
        num_object_points=num_object,
        num_scene_points=num_scene,
        input_features={
            OBJECT_KEY: PolicyFeature(type=FeatureType.STATE, shape=(num_object, 3)),
            SCENE_KEY: PolicyFeature(type=FeatureType.STATE, shape=(num_scene, 3)),
        },
        output_features={ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(num_object, 3))},
    )
    checkpoint = tmp_path / "checkpoint"
    TaxDPDPolicy(config).save_pretrained(checkpoint)
    for pipeline in make_taxdpd_pre_post_processors(config):
        pipeline.save_pretrained(checkpoint)
    output = tmp_path / "eval"
    run_cli(
        "lerobot-eval",
        f"--policy.path={checkpoint}",
        "--env.type=taxdpd_sim",
        "--env.task=insert_ssd",
        "--policy.num_inference_steps=2",
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
        "--policy.device=cpu",
        f"--output_dir={output}",
    )
    info = json.loads((output / "eval_info.json").read_text())
    assert info["overall"]["n_episodes"] == 1
    # The video shows the start scene, then the object where the predicted goal put it.
    (video,) = info["overall"]["video_paths"]
    frames = imageio.mimread(video)
    assert len(frames) == 2 and np.abs(frames[1].astype(int) - frames[0]).max() > 0
