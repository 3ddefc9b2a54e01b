"""Processor steps for point-cloud observations, shared by the `taxdpd` and `gc_dp3` pipelines."""

from __future__ import annotations

from dataclasses import dataclass

from lerobot.configs.types import PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry
from torch import Tensor

from lerobot_taxdpd.schema import POINT_CLOUD_PREFIX


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
