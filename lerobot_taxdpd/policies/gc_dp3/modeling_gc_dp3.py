"""Goal-conditioned 3D Diffusion Policy (`gc_dp3`): DP3 whose point input also holds the goal cloud.

Per observation step the clouds [cloth, hanger, goal] are concatenated, each point tagged with its
block's one-hot segment, and encoded by DP3's compact encoder; a small MLP encodes the end-effector
state; both features of the last `n_obs_steps` steps condition LeRobot's 1-D U-Net of the diffusion
policy through FiLM. The U-Net denoises a chunk of `horizon` normalised actions with DDIM (sample
prediction, few steps). Only the goal-conditioned point encoder and the policy around it are ours.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path

import torch
import torch.nn.functional as F  # noqa: N812
from diffusers.schedulers.scheduling_ddim import DDIMScheduler
from huggingface_hub import ModelCard
from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.policies.utils import populate_queues
from torch import Tensor, nn

from lerobot_taxdpd.data.schema import ACTION_KEY, STATE_KEY
from lerobot_taxdpd.policies.checkpoints import CheckedLoading
from lerobot_taxdpd.policies.ema import EmaWeights
from lerobot_taxdpd.policies.gc_dp3.configuration_gc_dp3 import GcDp3Config
from lerobot_taxdpd.policies.gc_dp3.model_card import render_model_card
from lerobot_taxdpd.policies.mixed_precision import warn_if_amp_is_slow
from lerobot_taxdpd.policies.model_cards import load_metrics, save_metrics


# --------------------------------------------------------------------------------------------- encoders
class PointCloudEncoder(nn.Module):
    """DP3's encoder: a per-point MLP with LayerNorm, max-pooled over points, then a projection."""

    def __init__(self, in_channels: int, hidden_dims: tuple[int, ...], out_dim: int) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        for dim in hidden_dims:
            layers += [nn.Linear(in_channels, dim), nn.LayerNorm(dim), nn.ReLU()]
            in_channels = dim
        self.point_mlp = nn.Sequential(*layers)
        self.projection = nn.Sequential(nn.Linear(in_channels, out_dim), nn.LayerNorm(out_dim))

    def forward(self, points: Tensor) -> Tensor:
        """(B, N, C) -> (B, out_dim)."""
        return self.projection(self.point_mlp(points).max(dim=1).values)


def mlp(in_dim: int, dims: tuple[int, ...]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, dim in enumerate(dims):
        layers.append(nn.Linear(in_dim, dim))
        if i < len(dims) - 1:
            layers.append(nn.ReLU())
        in_dim = dim
    return nn.Sequential(*layers)


# -------------------------------------------------------------------------------------------- the net
class GcDp3Model(nn.Module):
    """Observation encoders, denoiser and noise schedule; knows nothing of queues or normalisation."""

    def __init__(self, config: GcDp3Config) -> None:
        super().__init__()
        self.config = config
        center, scale = config.cloud_frame()
        # Not saved in the state dict: config.json carries them, so checkpoints of every mode load alike.
        self.register_buffer("cloud_center", torch.tensor(center), persistent=False)
        self.register_buffer("cloud_scale", torch.tensor(scale), persistent=False)
        num_blocks = len(config.cloud_keys)
        self.point_encoder = PointCloudEncoder(3 + num_blocks, config.point_encoder_dims, config.point_feature_dim)
        state_dim = config.input_features[STATE_KEY].shape[0]
        self.state_encoder = mlp(state_dim, config.state_encoder_dims)
        step_dim = config.point_feature_dim + config.state_encoder_dims[-1]
        self.action_dim = config.output_features[ACTION_KEY].shape[0]
        # LeRobot's diffusion-policy U-Net reads the sizes it needs (down_dims, kernel_size, n_groups,
        # diffusion_step_embed_dim, use_film_scale_modulation, action_feature) from this config.
        self.unet = DiffusionConditionalUnet1d(config, global_cond_dim=step_dim * config.n_obs_steps)
        self.scheduler = DDIMScheduler(
            num_train_timesteps=config.num_train_timesteps,
            beta_schedule=config.beta_schedule,
            clip_sample=config.clip_sample,
            clip_sample_range=config.clip_sample_range,
            prediction_type=config.prediction_type,
            set_alpha_to_one=True,
            steps_offset=0,
        )

    def segmented_cloud(self, batch: dict[str, Tensor]) -> Tensor:
        """Concatenate the clouds (..., N_k, 3) into (..., sum N_k, 3 + K), each row tagged with its block,
        in the clouds' shared frame (the identity unless `cloud_normalization="isotropic"`)."""
        blocks = []
        for index, key in enumerate(self.config.cloud_keys):
            points = (batch[key][..., : self.config.points_per_cloud, :] - self.cloud_center) / self.cloud_scale
            tag = F.one_hot(torch.tensor(index, device=points.device), len(self.config.cloud_keys))
            blocks.append(torch.cat([points, tag.to(points.dtype).expand(*points.shape[:-1], -1)], dim=-1))
        return torch.cat(blocks, dim=-2)

    def global_condition(self, batch: dict[str, Tensor]) -> Tensor:
        """Observation features of the last n_obs_steps steps, flattened: (B, n_obs_steps * step_dim)."""
        cloud = self.segmented_cloud(batch)  # (B, T, N, C)
        b, t = cloud.shape[:2]
        point_features = self.point_encoder(cloud.flatten(0, 1)).reshape(b, t, -1)
        state_features = self.state_encoder(batch[STATE_KEY])
        return torch.cat([point_features, state_features], dim=-1).flatten(1)

    def compute_loss(self, batch: dict[str, Tensor]) -> Tensor:
        actions = batch[ACTION_KEY]
        cond = self.global_condition(batch)
        noise = torch.randn_like(actions)
        steps = torch.randint(0, self.config.num_train_timesteps, (actions.shape[0],), device=actions.device)
        noisy = self.scheduler.add_noise(actions, noise, steps)
        prediction = self.unet(noisy, steps, cond)
        target = actions if self.config.prediction_type == "sample" else noise
        loss = F.mse_loss(prediction, target, reduction="none")
        if self.config.do_mask_loss_for_padding and "action_is_pad" in batch:
            loss = loss * (~batch["action_is_pad"]).unsqueeze(-1)
        return loss.mean()

    @torch.no_grad()
    def generate_actions(self, batch: dict[str, Tensor], generator: torch.Generator | None = None) -> Tensor:
        """Denoise a chunk from Gaussian noise: (B, horizon, action_dim), normalised units."""
        cond = self.global_condition(batch)
        sample = torch.randn(
            cond.shape[0], self.config.horizon, self.action_dim, device=cond.device, dtype=cond.dtype,
            generator=generator,
        )
        self.scheduler.set_timesteps(self.config.num_inference_steps)
        for t in self.scheduler.timesteps:
            steps = torch.full((cond.shape[0],), int(t), device=cond.device, dtype=torch.long)
            output = self.unet(sample, steps, cond)
            sample = self.scheduler.step(output, t, sample, generator=generator).prev_sample
        return sample


# ------------------------------------------------------------------------------------------ the policy
class GcDp3Policy(CheckedLoading, EmaWeights, PreTrainedPolicy):
    """LeRobot policy around `GcDp3Model`: observation queues, action chunking and the optional EMA."""

    config_class = GcDp3Config
    name = "gc_dp3"

    def __init__(self, config: GcDp3Config, dataset_stats: dict | None = None, **kwargs) -> None:
        super().__init__(config)
        config.validate_features()
        warn_if_amp_is_slow(config)
        config.derive_cloud_frame(dataset_stats)
        self.config = config
        self.model = GcDp3Model(config)
        self._init_ema()
        self._queues: dict[str, deque] = {}
        self.metrics: dict = {}  # measured results saved beside the weights (metrics.json), e.g. when shipped
        self.reset()

    def _save_pretrained(self, save_directory: Path) -> None:
        super()._save_pretrained(save_directory)
        save_metrics(self.metrics, save_directory)
        card = self.generate_model_card(None, self.name, self.config.license, self.config.tags)
        card.save(str(Path(save_directory) / "README.md"))

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path, **kwargs):
        policy = super().from_pretrained(pretrained_name_or_path, **kwargs)
        policy.metrics = load_metrics(pretrained_name_or_path, kwargs)
        return policy

    def generate_model_card(self, dataset_repo_id, model_type, license, tags) -> ModelCard:
        return render_model_card(self.config, self.metrics, dataset_repo_id, license, tags)

    def reset(self) -> None:
        steps = self.config.n_obs_steps
        self._queues = {key: deque(maxlen=steps) for key in self._observation_keys}
        self._queues[ACTION_KEY] = deque(maxlen=self.config.n_action_steps)

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, None]:
        return self.model.compute_loss(batch), None

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], generator: torch.Generator | None = None) -> Tensor:
        """The next `n_action_steps` normalised actions (B, n_action_steps, A) from the queued observations."""
        self._queue_observation(batch)
        stacked = {key: torch.stack(list(self._queues[key]), dim=1) for key in self._observation_keys}
        return self.inference_model.generate_actions(stacked, generator)[:, : self.config.n_action_steps]

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], generator: torch.Generator | None = None) -> Tensor:
        """One action (B, A) per env step; a new chunk is denoised every `n_action_steps` steps."""
        if not self._queues[ACTION_KEY]:
            self._queues[ACTION_KEY].extend(self.predict_action_chunk(batch, generator).transpose(0, 1))
        else:
            self._queue_observation(batch)
        return self._queues[ACTION_KEY].popleft()

    @property
    def _observation_keys(self) -> tuple[str, ...]:
        return (*self.config.cloud_keys, STATE_KEY)

    def _queue_observation(self, batch: dict[str, Tensor]) -> None:
        """Check the observation and push it; other keys (a processed batch carries `action`) are left out."""
        for key in self._observation_keys:
            if key not in batch:
                raise KeyError(f"gc_dp3: observation is missing '{key}' (got {sorted(batch)})")
            if not torch.isfinite(batch[key]).all():
                raise ValueError(f"gc_dp3: observation '{key}' contains NaN or infinite values")
        self._queues = populate_queues(self._queues, {key: batch[key] for key in self._observation_keys})
