"""Configuration of the goal-conditioned 3D Diffusion Policy (`--policy.type=gc_dp3`) for cloth hanging.

DP3 (Ze et al. 2024) with TAX-DPD's one change: the goal cloud is concatenated to the observed clouds,
every block tagged with a one-hot segment channel. Trained on ground-truth goals, run on predicted ones.

Time steps: DP3's cloth variant uses horizon 4, 2 observation steps and 4 action steps. DP3 counts its
horizon from the oldest observation, which would leave only 3 of 4 planned actions executable; here the
horizon counts from the current step (actions t .. t+3), so all 4 planned actions can run.

Sizes: DP3's U-Net has down_dims (512, 1024, 2048), about 255M parameters, impractical on a CPU. The
default here is (64, 128, 256) with a narrower point encoder (about 5.4M parameters); pass
`--policy.down_dims='[512,1024,2048]' --policy.point_encoder_dims='[64,128,256]'` for the paper's size.

Normalisation: state and action are mapped to [-1, 1] with the dataset's min/max (as DP3 does). Point
clouds (`cloud_normalization`): "isotropic" centres every cloud on one origin and divides it by one scale,
both derived once from the dataset's cloud statistics and saved in config.json, so object, hanger and goal
keep their shared geometry (DESIGN: never per axis); "none" feeds them in metres; "per_axis" lets LeRobot's
normaliser min-max them per axis and per cloud like the state (what the resumed legs of the first shipped
executor saw, by accident; docs/cloth.md). LeRobot types every `observation.*` key as STATE, and its
trainer rebuilds the normaliser from all input features whenever it starts from a checkpoint
(`--resume=true`, `--policy.path`), so except with "per_axis" the clouds are retyped ENV, which this config
maps to IDENTITY: the normaliser never touches them, on every path.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from lerobot.configs.policies import PreTrainedConfig
from lerobot.configs.types import FeatureType, NormalizationMode, PolicyFeature
from lerobot.optim.schedulers import DiffuserSchedulerConfig

from lerobot_taxdpd.data.schema import (
    ACTION_KEY,
    GOAL_CLOUD_KEY,
    OBJECT_KEY,
    POINT_CLOUD_PREFIX,
    SCENE_KEY,
    STATE_KEY,
)
from lerobot_taxdpd.policies.optim import FusedAdamWConfig

PREDICTION_TYPES = ("sample", "epsilon")
CLOUD_NORMALIZATIONS = ("none", "isotropic", "per_axis")


@PreTrainedConfig.register_subclass("gc_dp3")
@dataclass
class GcDp3Config(PreTrainedConfig):
    # ---- inputs / outputs
    n_obs_steps: int = 2
    horizon: int = 4
    n_action_steps: int = 4
    # Clouds concatenated in this order; block k carries one-hot segment k. Drop the goal key for plain DP3.
    cloud_keys: tuple[str, ...] = (OBJECT_KEY, SCENE_KEY, GOAL_CLOUD_KEY)
    # Points kept per cloud (None: all): the first rows, which is a farthest-point subset because this
    # project stores every cloud in farthest-point-sampling order. Fewer points make CPU training cheaper.
    points_per_cloud: int | None = None
    # How the clouds enter the network (module docstring): "isotropic", "none" or "per_axis" (docs/cloth.md).
    cloud_normalization: str = "isotropic"
    # "isotropic": the clouds' shared origin (metres) and metres per unit; derived from the dataset when unset.
    cloud_center: list[float] | None = None
    cloud_scale: float | None = None
    normalization_mapping: dict[str, NormalizationMode] = field(
        default_factory=lambda: {
            "VISUAL": NormalizationMode.IDENTITY,
            "STATE": NormalizationMode.MIN_MAX,
            "ENV": NormalizationMode.IDENTITY,
            "ACTION": NormalizationMode.MIN_MAX,
        }
    )

    # ---- point and state encoders (DP3: per-point MLP 64-128-256 with LayerNorm, max-pool, 64-d output)
    point_encoder_dims: tuple[int, ...] = (32, 64, 128)
    point_feature_dim: int = 64
    state_encoder_dims: tuple[int, ...] = (64, 64)

    # ---- LeRobot's 1-D conditional U-Net (lerobot.policies.diffusion) with FiLM
    down_dims: tuple[int, ...] = (64, 128, 256)
    kernel_size: int = 5
    n_groups: int = 8
    diffusion_step_embed_dim: int = 128
    use_film_scale_modulation: bool = True  # DP3 and LeRobot: the condition scales and shifts (False: shifts)

    # ---- noise schedule (DDIM, sample prediction, few inference steps)
    num_train_timesteps: int = 100
    beta_schedule: str = "squaredcos_cap_v2"
    prediction_type: str = "sample"
    clip_sample: bool = True
    clip_sample_range: float = 1.0
    num_inference_steps: int = 10
    do_mask_loss_for_padding: bool = False

    # ---- exponential moving average of the weights (DP3: power 0.75, max decay 0.9999)
    use_ema: bool = False
    ema_power: float = 0.75
    ema_max_decay: float = 0.9999

    # ---- optimisation (DP3: AdamW 1e-4, betas (0.95, 0.999), wd 1e-6, cosine with 500 warm-up steps)
    optimizer_lr: float = 1e-4
    optimizer_betas: tuple[float, float] = (0.95, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-6
    optimizer_grad_clip_norm: float = 10.0
    scheduler_name: str = "cosine"
    scheduler_warmup_steps: int = 500

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 1 <= self.n_action_steps <= self.horizon:
            raise ValueError(f"n_action_steps: must lie in [1, horizon={self.horizon}], got {self.n_action_steps}")
        if self.n_obs_steps < 1:
            raise ValueError(f"n_obs_steps: must be at least 1, got {self.n_obs_steps}")
        if not self.cloud_keys:
            raise ValueError("cloud_keys: at least one point-cloud key is needed")
        downsampling = 2 ** (len(self.down_dims) - 1)
        if self.horizon % downsampling:
            raise ValueError(
                f"horizon ({self.horizon}) must be divisible by 2^(len(down_dims) - 1) = {downsampling}: "
                "the U-Net halves the time axis at every level but the last"
            )
        for dim in self.down_dims:
            if dim % self.n_groups:
                raise ValueError(f"down_dims: {dim} is not divisible by n_groups={self.n_groups} (GroupNorm)")
        if self.prediction_type not in PREDICTION_TYPES:
            raise ValueError(f"prediction_type: must be one of {PREDICTION_TYPES}, got {self.prediction_type!r}")
        if not 1 <= self.num_inference_steps <= self.num_train_timesteps:
            raise ValueError(
                f"num_inference_steps: must lie in [1, num_train_timesteps={self.num_train_timesteps}], "
                f"got {self.num_inference_steps}"
            )
        if self.points_per_cloud is not None and self.points_per_cloud < 1:
            raise ValueError(f"points_per_cloud: must be positive or None, got {self.points_per_cloud}")
        if self.normalization_mapping.get("ENV", NormalizationMode.IDENTITY) is not NormalizationMode.IDENTITY:
            raise ValueError(
                "normalization_mapping['ENV'] must be IDENTITY: point clouds are typed ENV to bypass the normaliser "
                "(cloud_normalization=per_axis normalises them per axis instead)"
            )
        if self.cloud_normalization not in CLOUD_NORMALIZATIONS:
            raise ValueError(
                f"cloud_normalization: must be one of {CLOUD_NORMALIZATIONS}, got {self.cloud_normalization!r}"
            )
        if self.cloud_center is not None and len(self.cloud_center) != 3:
            raise ValueError(f"cloud_center: expected 3 coordinates, got {self.cloud_center}")
        if self.cloud_scale is not None and not self.cloud_scale > 0:
            raise ValueError(f"cloud_scale: must be positive, got {self.cloud_scale}")

    def is_cloud(self, key: str) -> bool:
        """Whether an input feature is a point cloud (normalised by LeRobot's normaliser only "per_axis")."""
        return key in self.cloud_keys or key.startswith(POINT_CLOUD_PREFIX)

    # ---- LeRobot hooks
    def get_optimizer_preset(self) -> FusedAdamWConfig:
        return FusedAdamWConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> DiffuserSchedulerConfig:
        return DiffuserSchedulerConfig(name=self.scheduler_name, num_warmup_steps=self.scheduler_warmup_steps)

    def validate_features(self) -> None:
        """Check the dataset's features (clear errors naming the field), then type the clouds ENV (left to the
        policy) or, with `cloud_normalization="per_axis"`, STATE (min-max)."""
        for key in self.cloud_keys:
            if key not in self.input_features:
                raise ValueError(
                    f"gc_dp3 needs the input feature '{key}' (an (N, 3) point cloud); dataset features are "
                    f"{sorted(self.input_features)}"
                )
            shape = tuple(self.input_features[key].shape)
            if len(shape) != 2 or shape[1] != 3:
                raise ValueError(f"input feature '{key}': expected shape (N, 3), got {shape}")
        state = self.input_features.get(STATE_KEY)
        if state is None or len(state.shape) != 1:
            raise ValueError(f"gc_dp3 needs a 1-D input feature '{STATE_KEY}' (end-effector state)")
        action = self.output_features.get(ACTION_KEY)
        if action is None or len(action.shape) != 1:
            raise ValueError(f"gc_dp3 needs a 1-D output feature '{ACTION_KEY}' (end-effector deltas)")
        for key, feature in self.input_features.items():
            if feature.type is FeatureType.VISUAL:
                raise ValueError(f"gc_dp3 takes point clouds and state only; remove the image feature '{key}'")
        # LeRobot's normaliser override on resume and fine-tune normalises by type: ENV is IDENTITY.
        cloud_type = FeatureType.STATE if self.cloud_normalization == "per_axis" else FeatureType.ENV
        self.input_features = {
            key: PolicyFeature(type=cloud_type, shape=feature.shape) if self.is_cloud(key) else feature
            for key, feature in self.input_features.items()
        }

    def derive_cloud_frame(self, dataset_stats: dict[str, dict] | None) -> None:
        """For "isotropic": the origin and scale that map the bounding box of every cloud in the dataset
        into [-1, 1] along its longest side, from LeRobot's per-feature min/max (kept once set)."""
        if self.cloud_normalization != "isotropic" or (self.cloud_center is not None and self.cloud_scale is not None):
            return
        missing = [key for key in self.cloud_keys if key not in (dataset_stats or {})]
        if missing:
            raise ValueError(
                f"cloud_normalization=isotropic: no dataset statistics for {missing}; train on a dataset or give "
                "cloud_center and cloud_scale. A checkpoint saved before this option existed fed its clouds in "
                'metres: set "cloud_normalization": "none" in its config.json'
            )
        low = torch.stack([torch.as_tensor(dataset_stats[k]["min"]).reshape(-1, 3).amin(0) for k in self.cloud_keys])
        high = torch.stack([torch.as_tensor(dataset_stats[k]["max"]).reshape(-1, 3).amax(0) for k in self.cloud_keys])
        low, high = low.amin(0).double(), high.amax(0).double()
        self.cloud_center = ((low + high) / 2).tolist()
        self.cloud_scale = float((high - low).amax() / 2)

    def cloud_frame(self) -> tuple[list[float], float]:
        """The origin (metres) and scale the policy maps every cloud with: the identity unless "isotropic"."""
        if self.cloud_normalization != "isotropic":
            return [0.0, 0.0, 0.0], 1.0
        if self.cloud_center is None or self.cloud_scale is None:
            raise ValueError("cloud_normalization=isotropic needs cloud_center and cloud_scale (derive_cloud_frame)")
        return self.cloud_center, self.cloud_scale

    @property
    def observation_delta_indices(self) -> list[int]:
        return list(range(1 - self.n_obs_steps, 1))

    @property
    def action_delta_indices(self) -> list[int]:
        return list(range(self.horizon))

    @property
    def reward_delta_indices(self) -> None:
        return None
