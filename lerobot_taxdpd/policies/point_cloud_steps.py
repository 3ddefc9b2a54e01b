"""Processor steps for point-cloud observations, shared by the `taxdpd` and `gc_dp3` pipelines."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs.types import PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, PolicyActionProcessorStep, ProcessorStepRegistry
from lerobot.utils.constants import ACTION, OBS_ENV_STATE
from torch import Tensor

from lerobot_taxdpd.data.schema import OBJECT_KEY, POINT_CLOUD_PREFIX, SCENE_KEY


@dataclass
@ProcessorStepRegistry.register(name="taxdpd_point_cloud_batch")
class AddPointCloudBatchDimensionStep(ObservationProcessorStep):
    """Give unbatched (N, 3) point clouds a batch dimension.

    LeRobot's own batching step only knows states and images, so a single observation straight from a
    sensor or an env would otherwise reach the policy as (N, 3).
    """

    def observation(self, observation: dict[str, Tensor]) -> dict[str, Tensor]:
        for key, value in observation.items():
            if key.startswith(POINT_CLOUD_PREFIX) and isinstance(value, Tensor) and value.dim() == 2:
                observation[key] = value.unsqueeze(0)
        return observation

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features


@dataclass
@ProcessorStepRegistry.register(name="taxdpd_unpack_environment_state")
class UnpackEnvironmentPointCloudsStep(ObservationProcessorStep):
    """Split `observation.environment_state` = [object rows; scene rows] into the two cloud keys.

    LeRobot 0.4.4's env loop forwards only a few observation keys, so the package's simulation envs send
    both clouds packed in `environment_state`, object first. Observations that already carry the cloud
    keys (datasets, direct calls) pass through untouched.
    """

    num_object_points: int = 0

    def observation(self, observation: dict[str, Tensor]) -> dict[str, Tensor]:
        packed = observation.get(OBS_ENV_STATE)
        if packed is None or OBJECT_KEY in observation or self.num_object_points <= 0:
            return observation
        observation = dict(observation)
        observation.pop(OBS_ENV_STATE)
        observation[OBJECT_KEY] = packed[..., : self.num_object_points, :]
        observation[SCENE_KEY] = packed[..., self.num_object_points :, :]
        return observation

    def get_config(self) -> dict[str, int]:
        return {"num_object_points": self.num_object_points}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        return features


@dataclass
@ProcessorStepRegistry.register(name="taxdpd_flatten_goal_cloud")
class FlattenGoalCloudStep(PolicyActionProcessorStep):
    """Flatten a batch of goal clouds (B, N_O, 3) into LeRobot's (B, action_dim) action layout.

    `lerobot-eval` and LeRobot's robot loops require 2-D actions, while the policy's `select_action`
    answers with clouds; the package's envs reshape the N_O * 3 values back into the cloud.
    """

    def action(self, action: Tensor) -> Tensor:
        return action.flatten(1) if action.dim() == 3 else action

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        action = features.get(PipelineFeatureType.ACTION, {}).get(ACTION)
        if action is not None and len(action.shape) == 2:
            flat = PolicyFeature(type=action.type, shape=(action.shape[0] * action.shape[1],))
            features[PipelineFeatureType.ACTION] = {**features[PipelineFeatureType.ACTION], ACTION: flat}
        return features
