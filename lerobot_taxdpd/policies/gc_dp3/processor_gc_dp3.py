"""Pre/post-processing pipelines of the `gc_dp3` policy.

LeRobot's standard steps are kept (rename, batch, device, normaliser; unnormaliser, device) because
`lerobot-train --policy.path` and `lerobot-eval` address them by registry name when they pass overrides.
The normaliser is given the state and action (min/max to [-1, 1] as in DP3) and, only with
`cloud_normalization="per_axis"`, the clouds; otherwise the policy scales them itself, isotropically or not
at all (they are typed ENV, mapped to IDENTITY, for LeRobot's resume override).
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

from lerobot_taxdpd.policies.gc_dp3.configuration_gc_dp3 import GcDp3Config
from lerobot_taxdpd.policies.point_cloud_steps import AddPointCloudBatchDimensionStep


def make_gc_dp3_pre_post_processors(
    config: GcDp3Config,
    dataset_stats: dict[str, dict[str, torch.Tensor]] | None = None,
) -> tuple[
    PolicyProcessorPipeline[dict[str, Any], dict[str, Any]],
    PolicyProcessorPipeline[PolicyAction, PolicyAction],
]:
    normalised = {
        key: feature
        for key, feature in {**config.input_features, **config.output_features}.items()
        if config.cloud_normalization == "per_axis" or not config.is_cloud(key)
    }
    stats = {key: value for key, value in (dataset_stats or {}).items() if key in normalised}
    preprocessor = PolicyProcessorPipeline[dict[str, Any], dict[str, Any]](
        steps=[
            RenameObservationsProcessorStep(rename_map={}),
            AddBatchDimensionProcessorStep(),
            AddPointCloudBatchDimensionStep(),
            DeviceProcessorStep(device=config.device),
            NormalizerProcessorStep(features=normalised, norm_map=config.normalization_mapping, stats=stats),
        ],
        name=POLICY_PREPROCESSOR_DEFAULT_NAME,
    )
    postprocessor = PolicyProcessorPipeline[PolicyAction, PolicyAction](
        steps=[
            UnnormalizerProcessorStep(
                features=config.output_features, norm_map=config.normalization_mapping, stats=stats
            ),
            DeviceProcessorStep(device="cpu"),
        ],
        name=POLICY_POSTPROCESSOR_DEFAULT_NAME,
        to_transition=policy_action_to_transition,
        to_output=transition_to_policy_action,
    )
    return preprocessor, postprocessor
