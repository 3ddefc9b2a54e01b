"""Pre/post-processing pipelines of the `taxdpd` policy.

LeRobot's standard steps are kept (rename, batch, device, normaliser; unnormaliser, device) because
`lerobot-train --policy.path` and `lerobot-eval` address them by registry name when they pass overrides.
The config maps every feature to IDENTITY: the policy rescales clouds isotropically itself. The
postprocessor hands actions out in LeRobot's (B, action_dim) layout: the goal cloud flattened row by row.
"""

from __future__ import annotations

from typing import Any

import torch
from lerobot.processor import (
    AddBatchDimensionProcessorStep,
    DeviceProcessorStep,
    NormalizerProcessorStep,
    PolicyAction,
    PolicyProcessorPipeline,
    RenameObservationsProcessorStep,
    UnnormalizerProcessorStep,
)
from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action
from lerobot.utils.constants import POLICY_POSTPROCESSOR_DEFAULT_NAME, POLICY_PREPROCESSOR_DEFAULT_NAME

from lerobot_taxdpd.data.schema import OBJECT_KEY
from lerobot_taxdpd.policies.point_cloud_steps import (
    AddPointCloudBatchDimensionStep,
    FlattenGoalCloudStep,
    UnpackEnvironmentPointCloudsStep,
)
from lerobot_taxdpd.policies.taxdpd.configuration_taxdpd import TaxDPDConfig


def make_taxdpd_pre_post_processors(
    config: TaxDPDConfig,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    features = {**config.input_features, **config.output_features}
    object_feature = config.input_features.get(OBJECT_KEY)
    num_object_points = object_feature.shape[0] if object_feature is not None else 0
    preprocessor = PolicyProcessorPipeline[dict[str, Any], dict[str, Any]](
        steps=[
            RenameObservationsProcessorStep(rename_map={}),
            UnpackEnvironmentPointCloudsStep(num_object_points=num_object_points),
            AddBatchDimensionProcessorStep(),
            AddPointCloudBatchDimensionStep(),
            DeviceProcessorStep(device=config.device),
            NormalizerProcessorStep(features=features, norm_map=config.normalization_mapping, stats=dataset_stats),
        ],
        name=POLICY_PREPROCESSOR_DEFAULT_NAME,
    )
    postprocessor = PolicyProcessorPipeline[PolicyAction, PolicyAction](
        steps=[
            UnnormalizerProcessorStep(
                features=config.output_features, norm_map=config.normalization_mapping, stats=dataset_stats
            ),
            DeviceProcessorStep(device="cpu"),
            FlattenGoalCloudStep(),
        ],
        name=POLICY_POSTPROCESSOR_DEFAULT_NAME,
        to_transition=policy_action_to_transition,
        to_output=transition_to_policy_action,
    )
    return preprocessor, postprocessor
