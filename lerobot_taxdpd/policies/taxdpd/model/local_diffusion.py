"""Local configuration refinement: point-cloud diffusion of the goal in the placement frame g.

Token construction (paper, Method Details):
- reconstruction embedding: one encoder over [current goal estimate (flag 1) | scene (flag 0)], split
  into object-side and scene-side features; the scene side become the scene tokens;
- object embedding: the initial, mean-centred object (constant while sampling, so computed once);
- deformation embedding: per-point [shape estimate, displacement, zero-mean displacement] (9 channels);
- token mixing: a linear layer from the concatenated object-side streams to `hidden_dim`;
- with `position_octaves` (not in the paper): Fourier features of each token's position added to the object
  tokens (the goal estimate) and the scene tokens (see `positions.py`).
Object tokens plus a learnable frame token go through the DiT, cross-attending to the scene tokens; the
frame token is read out by the frame head and the object tokens by the shape head.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from lerobot_taxdpd.maths.geometry import principal_spreads, small_rotation_between
from lerobot_taxdpd.policies.taxdpd.model.dit import DiT, OutputHead, TimestepEmbedding
from lerobot_taxdpd.policies.taxdpd.model.parameterizations import State, make_parameterization, randn_like
from lerobot_taxdpd.policies.taxdpd.model.pointnet2 import (
    Grouping,
    SamplingLayout,
    cloud_layouts,
    concat_layouts,
    make_encoder,
)
from lerobot_taxdpd.policies.taxdpd.model.positions import FourierPositions
from lerobot_taxdpd.policies.taxdpd.schedulers import DDIMSampler, make_training_scheduler, training_target


@dataclass
class DenoiserContext:
    """Everything that stays fixed while one batch is denoised."""

    object_centred: Tensor  # (B, N, 3)
    scene: Tensor  # (B, M, 3), placement frame
    object_layout: SamplingLayout | None
    object_grouping: Grouping | None
    object_features: Tensor  # (B, N, dim)
    reconstruction_layout: SamplingLayout | None
    reconstruction_flags: Tensor | None  # (B, N + M, 1): 1 on the goal estimate's points, 0 on the scene's
    scene_features: Tensor | None  # scene tokens when there is no reconstruction embedding
    scene_positions: Tensor | None  # Fourier features of the scene's points, with position_octaves


@dataclass
class StepConditioning:
    """What the denoiser derives from the timestep alone: the DiT's and the output heads' modulations."""

    backbone: Tensor  # (B, blocks * 9 * dim)
    point_head: tuple[Tensor, Tensor] | None  # shift and 1 + scale, (B, dim) each
    frame_head: tuple[Tensor, Tensor] | None

    def step(self, index: int, batch: int) -> StepConditioning:
        """Row `index` (one timestep of several computed together) for a batch of `batch` clouds: views only."""

        def row(x: Tensor) -> Tensor:
            return x[index].expand(batch, -1)

        def head(modulation: tuple[Tensor, Tensor] | None) -> tuple[Tensor, Tensor] | None:
            return None if modulation is None else (row(modulation[0]), row(modulation[1]))

        return StepConditioning(row(self.backbone), head(self.point_head), head(self.frame_head))


def _empty_channels(x: Tensor) -> Tensor:
    return x.new_zeros(*x.shape[:-1], 0)


class LocalDenoiser(nn.Module):
    """Predicts the noise of every diffused variable from the current goal estimate."""

    def __init__(self, config, frame_dim: int | None, has_point_output: bool) -> None:
        super().__init__()
        dim = config.hidden_dim
        self.config = config
        self.use_reconstruction = config.use_reconstruction_embedding
        self.use_deformation = config.use_deformation_embedding
        if self.use_reconstruction:
            self.reconstruction_encoder = make_encoder(config, in_channels=1)
        else:
            self.estimate_encoder = make_encoder(config, in_channels=0)
            self.scene_encoder = make_encoder(config, in_channels=0)
        self.object_encoder = make_encoder(config, in_channels=0)
        if self.use_deformation:
            self.deformation_encoder = make_encoder(config, in_channels=9)
        self.token_mixing = nn.Linear((3 if self.use_deformation else 2) * dim, dim)
        self.positions = FourierPositions(dim, config.position_octaves) if config.position_octaves else None
        self.timestep_embedding = TimestepEmbedding(dim, config.timestep_embed_dim)
        self.frame_token = nn.Parameter(torch.randn(1, 1, dim) * 0.02) if frame_dim else None
        self.backbone = DiT(dim, config.num_heads, config.num_blocks, config.mlp_ratio)
        self.point_head = OutputHead(dim, 3) if has_point_output else None
        self.frame_head = OutputHead(dim, frame_dim) if frame_dim else None

    def context(
        self,
        object_centred: Tensor,
        scene: Tensor,
        layouts: list[SamplingLayout] | None = None,
        object_grouping: Grouping | None = None,
    ) -> DenoiserContext:
        """Cache the work that does not depend on the goal estimate.

        `object_centred` is (B, N, 3); `scene` may hold K placement frames per object, (B * K, M, 3): K
        translated copies of each scene, or K local scenes, one around each frame. Object-only work is done once
        per object and repeated. `layouts` are the object's (B rows) and the scene's, when the caller has them
        already: B rows for translated copies (FPS does not change under translation), B * K for local scenes;
        `object_grouping` the object's grouping (B rows), when the caller shares it with the Dense GMM.
        """
        repeats = scene.shape[0] // object_centred.shape[0]
        if layouts is None:
            layouts = cloud_layouts(self.config, [object_centred, scene[::repeats]])
        object_layout, scene_layout = layouts if layouts is not None else (None, None)
        if scene_layout is not None and scene_layout.level1.shape[0] != scene.shape[0]:
            scene_layout = scene_layout.repeat_interleave(repeats)
        reconstruction_layout = reconstruction_flags = scene_features = None
        if self.use_reconstruction:
            b, n, m = scene.shape[0], object_centred.shape[1], scene.shape[1]
            reconstruction_flags = torch.cat([scene.new_ones(b, n, 1), scene.new_zeros(b, m, 1)], 1)
            if layouts is not None:
                reconstruction_layout = concat_layouts([object_layout.repeat_interleave(repeats), scene_layout], [n, m])
        else:
            scene_features = self.scene_encoder(scene, _empty_channels(scene), layout=scene_layout)
        if object_grouping is None and object_layout is not None:
            object_grouping = self.object_encoder.group(object_centred, object_layout)
        if object_grouping is not None:  # every pass of the object and deformation encoders reuses it
            object_grouping = object_grouping.cast(self.object_encoder.compute_dtype(object_centred))
        object_features = self.object_encoder(
            object_centred, _empty_channels(object_centred), layout=object_layout, grouping=object_grouping
        )
        scene_positions = self.positions(scene) if self.positions is not None else None
        if repeats > 1:
            object_centred = object_centred.repeat_interleave(repeats, 0)
            object_features = object_features.repeat_interleave(repeats, 0)
            object_layout = object_layout.repeat_interleave(repeats) if object_layout else None
            object_grouping = object_grouping.repeat_interleave(repeats) if object_grouping else None
        return DenoiserContext(
            object_centred,
            scene,
            object_layout,
            object_grouping,
            object_features,
            reconstruction_layout,
            reconstruction_flags,
            scene_features,
            scene_positions,
        )

    def conditioning(self, t: Tensor) -> StepConditioning:
        """The modulations of timesteps `t` (B,)."""
        condition = self.timestep_embedding(t)
        return StepConditioning(
            self.backbone.modulations_of(condition),
            self.point_head.modulation_of(condition) if self.point_head is not None else None,
            self.frame_head.modulation_of(condition) if self.frame_head is not None else None,
        )

    def forward(
        self,
        context: DenoiserContext,
        goal_estimate: Tensor,
        shape_estimate: Tensor,
        conditioning: StepConditioning,
    ) -> tuple[Tensor | None, Tensor | None]:
        n = goal_estimate.shape[1]
        if self.use_reconstruction:
            xyz = torch.cat([goal_estimate, context.scene], 1)
            features = self.reconstruction_encoder(
                xyz, context.reconstruction_flags, layout=context.reconstruction_layout
            )
            estimate_features, scene_tokens = features[:, :n], features[:, n:]
        else:
            estimate_features = self.estimate_encoder(
                goal_estimate, _empty_channels(goal_estimate), layout=context.object_layout
            )
            scene_tokens = context.scene_features
        streams = [estimate_features, context.object_features]
        if self.use_deformation:
            displacement = goal_estimate - context.object_centred
            deformation_input = torch.cat([shape_estimate, displacement, shape_estimate - context.object_centred], -1)
            streams.append(
                self.deformation_encoder(
                    context.object_centred,
                    deformation_input,
                    layout=context.object_layout,
                    grouping=context.object_grouping,
                )
            )
        tokens = self.token_mixing(torch.cat(streams, -1))
        if self.positions is not None:
            tokens = tokens + self.positions(goal_estimate).to(tokens.dtype)
            scene_tokens = scene_tokens + context.scene_positions.to(scene_tokens.dtype)
        if self.frame_token is not None:
            tokens = torch.cat([tokens, self.frame_token.expand(tokens.shape[0], -1, -1).to(tokens.dtype)], 1)
        tokens = self.backbone(tokens, scene_tokens, modulations=conditioning.backbone)
        point_out = frame_out = None
        if self.point_head is not None:  # in the layers' dtype: the parameterisation's split makes it fp32
            point_out = self.point_head(tokens[:, :n], modulation=conditioning.point_head)
        if self.frame_head is not None:
            frame_out = self.frame_head(tokens[:, n:], modulation=conditioning.frame_head)[:, 0].float()
        return point_out, frame_out


class LocalDiffusion(nn.Module):
    """DDPM over the goal in the placement frame: training loss and few-step sampling."""

    def __init__(self, config) -> None:
        super().__init__()
        self.parameterization = make_parameterization(config)
        self.denoiser = LocalDenoiser(config, self.parameterization.frame_dim, self.parameterization.has_point_output)
        self.training_scheduler = make_training_scheduler(config)
        self.sampler = DDIMSampler(config)
        self.rotation_noise_std = math.radians(config.rotation_noise_std_deg) if config.use_rotation_noise else 0.0
        self.rotation_noise = config.rotation_noise
        self.rotation_loss_weight = config.rotation_loss_weight
        self.spread_loss_weight = config.spread_loss_weight

    def _predict(self, context: DenoiserContext, state: State, conditioning: StepConditioning) -> State:
        goal_estimate, shape_estimate = self.parameterization.compose(state, context.object_centred)
        return self.parameterization.split(*self.denoiser(context, goal_estimate, shape_estimate, conditioning))

    def loss(
        self,
        object_centred: Tensor,
        scene: Tensor,
        goal: Tensor,
        generator: torch.Generator | None = None,
        layouts: list[SamplingLayout] | None = None,
        object_grouping: Grouping | None = None,
    ) -> dict[str, Tensor]:
        """Denoising losses for clean goals (B, N, 3) in the placement frame, against the configured target."""
        param, scheduler = self.parameterization, self.training_scheduler
        clean = param.encode(goal, object_centred)
        device = generator.device if generator is not None else goal.device
        t = torch.randint(0, scheduler.config.num_train_timesteps, (goal.shape[0],), generator=generator, device=device)
        t = t.to(goal.device)
        alpha_bar = scheduler.alphas_cumprod.to(t.device)[t]  # the share of the clean goal left at t
        signal = clean
        if self.rotation_noise == "signal" and self.rotation_noise_std > 0:
            # The rotation perturbs the signal itself, by less as the noise fades, so that the last timestep
            # is pure noise (where sampling starts) and the target stays the unturned goal.
            noise_level = (1.0 - alpha_bar).sqrt()
            signal = param.turn_shape(clean, self.rotation_noise_std * noise_level, generator)
            noise = param.sample_noise(clean, 0.0, generator)
        else:
            noise = param.sample_noise(clean, self.rotation_noise_std, generator)
        noisy = {k: scheduler.add_noise(signal[k], noise[k], t) for k in clean}
        target = {k: training_target(scheduler, clean[k], noise[k], t) for k in clean}
        context = self.denoiser.context(object_centred, scene, layouts, object_grouping)
        predicted = self._predict(context, noisy, self.denoiser.conditioning(t))
        losses = param.loss(predicted, target)
        if self.rotation_loss_weight == 0 and self.spread_loss_weight == 0:
            return losses
        # The pose- and shape-level terms are weighted by the signal left at t: near pure noise the clean
        # estimate blends the modes, and its turn and extent mean nothing.
        true_shape, predicted_shape = param.centred_shape(clean), param.centred_shape(predicted)
        if self.rotation_loss_weight > 0:
            turn = small_rotation_between(true_shape, predicted_shape)
            losses["loss_pose_rotation"] = (alpha_bar.to(turn.dtype) * turn.pow(2).sum(-1)).mean()
            losses["loss_local"] = losses["loss_local"] + self.rotation_loss_weight * losses["loss_pose_rotation"]
        if self.spread_loss_weight > 0:
            relative = principal_spreads(predicted_shape) / principal_spreads(true_shape) - 1.0
            losses["loss_shape_spread"] = (alpha_bar.to(relative.dtype) * relative.pow(2).sum(-1)).mean()
            losses["loss_local"] = losses["loss_local"] + self.spread_loss_weight * losses["loss_shape_spread"]
        return losses

    @torch.no_grad()
    def sample(
        self,
        object_centred: Tensor,
        scene: Tensor,
        num_inference_steps: int,
        *,
        eta: float = 0.0,
        generator: torch.Generator | None = None,
        layouts: list[SamplingLayout] | None = None,
        object_grouping: Grouping | None = None,
        frame_temperature: float = 1.0,
    ) -> Tensor:
        """Goal clouds (B * K, N, 3) in the placement frames of `scene` (B * K, M, 3). The frame's starting
        noise is scaled by `frame_temperature` (`TaxDPDConfig.frame_temperature`); the shape's is not."""
        context = self.denoiser.context(object_centred, scene, layouts, object_grouping)
        param, sampler = self.parameterization, self.sampler
        state = param.initial_state(context.object_centred, generator)
        if frame_temperature != 1.0 and "frame" in state:
            state["frame"] = state["frame"] * frame_temperature
        steps = list(sampler.steps(num_inference_steps))
        # The timesteps are known before the loop: their modulations are computed together, once.
        timesteps = torch.tensor([step.timestep for step in steps], device=scene.device)
        conditionings = self.denoiser.conditioning(timesteps)
        for index, step in enumerate(steps):
            predicted = self._predict(context, state, conditionings.step(index, scene.shape[0]))
            state = {
                k: sampler.step(predicted[k], step, state[k], eta, randn_like(state[k], generator) if eta > 0 else None)
                for k in state
            }
            if eta > 0:  # without noise the update combines the state and a prediction, both projected already
                state = param.project(state)
        return param.compose(state, context.object_centred)[0]
