"""`lerobot-eval --env.type=taxdpd_sim --env.task=<task>`: the benchmarks as LeRobot envs.

Imported by `lerobot_taxdpd/__init__.py`, so LeRobot's plugin discovery registers the env type and the
gymnasium ids; it stays light (no pybullet) until an env is actually made.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import gymnasium as gym
from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.envs.configs import EnvConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE

from lerobot_taxdpd.data.schema import DEFAULT_POINT_COUNTS

GYM_NAMESPACE = "lerobot_taxdpd"
#: Task name -> key of its (N_O, N_S) in DEFAULT_POINT_COUNTS; mirrors `lerobot_taxdpd.sim.tasks`.
TASK_POINT_COUNTS = {
    "mug_easyrack": "mug_rack_easy_single",
    "mug_medrack": "mug_rack_med_single",
    "mug_multi_medrack": "mug_rack_med_multi",
    "book_shelf": "book_on_bookshelf_double_view_rnd_ori",
    "can_cabinet": "can_in_cabinet_stack",
    "insert_waterproof": "nist",
    "insert_dsub25": "nist",
    "insert_ssd": "nist",
    "insert_waterproof_multi": "nist",
}

for _task in TASK_POINT_COUNTS:
    _id = f"{GYM_NAMESPACE}/{_task}-v0"
    if _id not in gym.registry:
        gym.register(
            id=_id, entry_point="lerobot_taxdpd.sim.gym_env:PlacementEnv", kwargs={"task": _task}, max_episode_steps=2
        )


@EnvConfig.register_subclass("taxdpd_sim")
@dataclass
class TaxDPDSimEnvConfig(EnvConfig):
    """One placement per episode on held-out geometry; observation = [object; scene] cloud, action = goal cloud."""

    task: str = "mug_easyrack"
    fps: int = 1
    split: str = "test"
    # Scene points observed per trial (default: the task's): as many as the predictor was trained on, when
    # its demonstrations were recorded denser (`sim generate --scene-cloud-size`).
    scene_cloud_size: int | None = None
    features: dict[str, PolicyFeature] = field(default_factory=dict)
    features_map: dict[str, str] = field(default_factory=lambda: {ACTION: ACTION, "environment_state": OBS_ENV_STATE})

    def __post_init__(self) -> None:
        if self.task not in TASK_POINT_COUNTS:
            raise ValueError(f"env.task: unknown task {self.task!r}; choose one of {', '.join(TASK_POINT_COUNTS)}")
        num_object, num_scene = DEFAULT_POINT_COUNTS[TASK_POINT_COUNTS[self.task]]
        num_scene = self.scene_cloud_size or num_scene
        self.features = {
            ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(num_object, 3)),
            "environment_state": PolicyFeature(type=FeatureType.ENV, shape=(num_object + num_scene, 3)),
        }

    @property
    def gym_id(self) -> str:
        return f"{GYM_NAMESPACE}/{self.task}-v0"

    @property
    def package_name(self) -> str:
        return "lerobot_taxdpd.sim.env_config"

    @property
    def gym_kwargs(self) -> dict:
        return {"split": self.split, "scene_cloud_size": self.scene_cloud_size}
