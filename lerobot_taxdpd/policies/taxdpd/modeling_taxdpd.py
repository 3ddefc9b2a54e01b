"""TAX-DPD as a LeRobot policy: `TaxDPDModel` holds both stages, `TaxDPDPolicy` talks to LeRobot and users.

Inputs and outputs of the policy are in metres in the caller's frame. Internally every cloud is moved to
the scene centroid and multiplied by `config.point_scale` ("model units"). One `lerobot-train` step
trains both stages: the Dense GMM on the true goal centroid, and the local diffusion in a placement frame
drawn around the true centroid (not from the GMM), as in the paper.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import numbers
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from huggingface_hub import ModelCard
from lerobot.policies.pretrained import PreTrainedPolicy
from torch import Tensor, nn

from lerobot_taxdpd.data.point_order import read_point_order
from lerobot_taxdpd.data.scaling import estimate_point_scale, object_radius
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.data.validation import (
    PointCloudError,
    check_point_cloud,
    check_same_shape,
    check_values_together,
    raise_value_faults,
    value_faults,
)
from lerobot_taxdpd.maths.geometry import (
    estimate_rigid_transform,
    farthest_point_sample_parts,
    gather_points,
    is_farthest_point_prefix,
    lift_point_motion,
    nearest_indices,
    nearest_points,
)
from lerobot_taxdpd.policies.checkpoints import CheckedLoading
from lerobot_taxdpd.policies.ema import EmaWeights
from lerobot_taxdpd.policies.mixed_precision import call_with_linears_cast, warn_if_amp_is_slow
from lerobot_taxdpd.policies.model_cards import load_metrics, save_metrics
from lerobot_taxdpd.policies.taxdpd.augmentation import (
    ball_cut,
    downsample_indices,
    plane_cut,
    random_start_pose,
    random_z_rotation,
)
from lerobot_taxdpd.policies.taxdpd.configuration_taxdpd import (
    GMM_FRAMES,
    TaxDPDConfig,
    check_frame_temperature,
    check_inference_steps,
)
from lerobot_taxdpd.policies.taxdpd.model.dense_gmm import DenseGMM
from lerobot_taxdpd.policies.taxdpd.model.dit import DiT
from lerobot_taxdpd.policies.taxdpd.model.local_diffusion import LocalDiffusion
from lerobot_taxdpd.policies.taxdpd.model.parameterizations import randn_like
from lerobot_taxdpd.policies.taxdpd.model.pointnet2 import Grouping, SamplingLayout, cloud_layouts, concat_layouts
from lerobot_taxdpd.policies.taxdpd.model_card import render_model_card

logger = logging.getLogger(__name__)

#: The clouds a training batch holds, in the order `forward` checks them.
CLOUD_KEYS = (OBJECT_KEY, SCENE_KEY, ACTION_KEY)

#: DDIM's stochasticity per sampler name: deterministic DDIM, or ancestral DDPM sampling.
SAMPLER_ETA = {"ddim": 0.0, "ddpm": 1.0}
#: How many times larger or smaller than the training objects an input object may be before a warning: the
#: objects of one task vary by a small factor; a unit mix-up (millimetres for metres) is a factor of 1000.
SCALE_TOLERANCE = 10.0


def centre_on_centroid(points: Tensor) -> tuple[Tensor, Tensor]:
    """Points (B, N, 3) moved to their centroid, and the centroid (B, 3): the object as both stages take it."""
    centroid = points.mean(1)
    return points - centroid.unsqueeze(1), centroid


class TaxDPDModel(nn.Module):
    """Dense GMM (global) + disentangled point diffusion (local).

    Every cloud it takes and returns is in model units, centred on the scene centroid (see `ModelFrame`):
    the scene's centroid is the origin, so the object's centroid is the object-to-scene offset.
    """

    def __init__(self, config: TaxDPDConfig) -> None:
        super().__init__()
        self.config = config
        self.global_stage = DenseGMM(config) if config.use_gmm else None
        self.local_stage = LocalDiffusion(config)

    def _gmm(
        self,
        object_centred: Tensor,
        object_centroid: Tensor,
        scene_points: Tensor,
        layouts: list[SamplingLayout] | None,
        object_grouping: Grouping | None = None,
    ) -> tuple[Tensor, Tensor]:
        """Mixing logits (B, M) and component means (B, M, 3), from the object centred on its centroid (B, 3)."""
        return self.global_stage(object_centred, scene_points, object_centroid, layouts, object_grouping)

    def _object_grouping(self, object_centred: Tensor, layouts: list[SamplingLayout] | None) -> Grouping | None:
        """The centred object's grouping, which both stages' object encoders and the deformation encoder share
        (same cloud, layout and radii), in the layers' dtype; None for the MLP encoders."""
        if layouts is None:
            return None
        encoder = self.local_stage.denoiser.object_encoder
        return encoder.group(object_centred, layouts[0]).cast(encoder.compute_dtype(object_centred))

    def forward(
        self,
        object_points: Tensor,
        scene_points: Tensor,
        goal_points: Tensor,
        *,
        fps_ordered: tuple[bool, bool] = (False, False),
        dense_scene: Tensor | None = None,
    ) -> dict[str, Tensor]:
        """The training losses (its call is the training pass). `fps_ordered`: whether the object and the scene
        clouds are in FPS order from their point 0 already;
        `dense_scene`: the scene as given, before its reduction to the network's point count, where the local
        stage takes its local scene from (default: `scene_points`)."""
        target = goal_points.mean(1)
        losses: dict[str, Tensor] = {}
        object_centred, object_centroid = centre_on_centroid(object_points)
        if self.global_stage is not None:
            frame = target + randn_like(target) * self.config.frame_noise_std
        else:
            frame = torch.zeros_like(target)  # the scene centroid
        clouds, ordered = [object_centred, scene_points], list(fps_ordered)
        if self.config.local_scene_points:
            clouds.append(self._local_scene(dense_scene if dense_scene is not None else scene_points, frame))
            ordered.append(False)
        layouts = cloud_layouts(self.config, clouds, ordered)  # one FPS pass serves both stages
        object_grouping = self._object_grouping(object_centred, layouts)
        if self.global_stage is not None:
            # The Dense GMM learns from the first part of the (shuffled) batch only: it converges long before
            # the local stage, so the rest of its share of the step is better spent on the local stage.
            n = max(1, round(target.shape[0] * self.config.gmm_batch_fraction))
            head = [layout.head(n) for layout in layouts[:2]] if layouts is not None else None
            grouping = object_grouping.head(n) if object_grouping is not None else None
            logits, means = self._gmm(object_centred[:n], object_centroid[:n], scene_points[:n], head, grouping)
            losses["loss_gmm"] = self.global_stage.loss(logits, means, target[:n])
        frame = frame.unsqueeze(1)
        local_scene, scene_layout = self._local_stage_scene(
            clouds[1], clouds[-1], *((layouts[1], layouts[-1]) if layouts is not None else (None, None))
        )
        local_layouts = [layouts[0], scene_layout] if layouts is not None else None
        losses.update(
            self.local_stage.loss(
                object_centred,
                local_scene - frame,
                goal_points - frame,
                layouts=local_layouts,
                object_grouping=object_grouping,
            )
        )
        losses["loss"] = losses["loss_local"] + losses.get("loss_gmm", 0.0)
        return losses

    def _local_stage_scene(
        self, scene: Tensor, crop: Tensor, scene_layout: SamplingLayout | None, crop_layout: SamplingLayout | None
    ) -> tuple[Tensor, SamplingLayout | None]:
        """The cloud the local stage sees and its layout: the crop alone, or the network's scene beside it
        (`local_scene_with_whole`), each part sampled on its own so that the crop keeps its density."""
        if not self.config.local_scene_with_whole:
            return crop, crop_layout
        if scene.shape[0] != crop.shape[0]:  # one scene, K crops (one around each sampled frame)
            repeats = crop.shape[0] // scene.shape[0]
            scene = scene.repeat_interleave(repeats, 0)
            scene_layout = scene_layout.repeat_interleave(repeats) if scene_layout is not None else None
        layout = None
        if scene_layout is not None:
            layout = concat_layouts([scene_layout, crop_layout], [scene.shape[1], crop.shape[1]])
        return torch.cat([scene, crop], 1), layout

    def _local_scene(self, dense_scene: Tensor, frames: Tensor) -> Tensor:
        """The local stage's scene: the `local_scene_points` points of each scene (B, M, 3) nearest its frame (B, 3)."""
        return nearest_points(dense_scene, frames, min(self.config.local_scene_points, dense_scene.shape[1]))

    def placement_distribution(self, object_points: Tensor, scene_points: Tensor) -> tuple[Tensor, Tensor]:
        if self.global_stage is None:
            raise RuntimeError(
                "this model was trained without the Dense GMM (use_gmm=false): it has no placement distribution"
            )
        logits, means = self._gmm(*centre_on_centroid(object_points), scene_points, None)
        return torch.softmax(logits, -1), means

    def sample(
        self,
        object_points: Tensor,
        scene_points: Tensor,
        num_samples: int,
        num_inference_steps: int,
        *,
        eta: float = 0.0,
        generator: torch.Generator | None = None,
        frames: Tensor | None = None,
        fps_ordered: tuple[bool, bool] = (False, False),
        dense_scene: Tensor | None = None,
        gmm_frames: str = "components",
        frame_temperature: float = 1.0,
    ) -> Tensor:
        """K goal clouds per scene: (B, N, 3), (B, M, 3) -> (B, K, N, 3). `frames` (B, 3), when given, are the
        placement frames of every sample instead of the Dense GMM's; `gmm_frames` says how the Dense GMM's
        are drawn (`TaxDPDConfig.gmm_frames`), `frame_temperature` how far from them the local stage starts
        (`TaxDPDConfig.frame_temperature`); `fps_ordered` and `dense_scene` as in `forward`."""
        b, n, _ = object_points.shape
        object_centred, object_centroid = centre_on_centroid(object_points)
        layouts = cloud_layouts(self.config, [object_centred, scene_points], fps_ordered)
        object_grouping = self._object_grouping(object_centred, layouts)
        if frames is not None:
            frames = frames.to(scene_points).unsqueeze(1).expand(b, num_samples, 3)
        elif self.global_stage is not None:
            logits, means = self._gmm(object_centred, object_centroid, scene_points, layouts, object_grouping)
            probabilities = torch.softmax(logits.float(), -1)
            if generator is not None:
                probabilities = probabilities.to(generator.device)
            component = torch.multinomial(probabilities, num_samples, replacement=True, generator=generator)
            frames = gather_points(means.float(), component.to(means.device))
            if gmm_frames == "modes":
                frames = self.global_stage.climb_to_modes(frames, probabilities.to(means.device), means)
        else:
            frames = scene_points.new_zeros(b, num_samples, 3)
        frames = frames.reshape(b * num_samples, 3)
        if self.config.local_scene_points:
            dense = (dense_scene if dense_scene is not None else scene_points).repeat_interleave(num_samples, 0)
            crop = self._local_scene(dense, frames)
            crop_layout = cloud_layouts(self.config, [crop])[0] if layouts is not None else None
            scene_local, scene_layout = self._local_stage_scene(
                scene_points, crop, layouts[1] if layouts is not None else None, crop_layout
            )
            layouts = [layouts[0], scene_layout] if layouts is not None else None
        else:
            scene_local = scene_points.repeat_interleave(num_samples, 0)
        frames = frames.unsqueeze(1)
        goals = self.local_stage.sample(
            object_centred,
            scene_local - frames,
            num_inference_steps,
            eta=eta,
            generator=generator,
            layouts=layouts,
            object_grouping=object_grouping,
            frame_temperature=frame_temperature,
        )
        return (goals + frames).reshape(b, num_samples, n, 3)


@dataclass(frozen=True)
class ModelFrame:
    """Metres in the caller's frame <-> model units: centred on the scene's centroid, scaled by `scale`."""

    origin: Tensor  # (B, 1, 3), metres
    scale: float  # model units per metre

    @classmethod
    def of_scene(cls, scene_points: Tensor, scale: float) -> ModelFrame:
        return cls(scene_points.mean(1, keepdim=True), scale)

    def to_model(self, points: Tensor) -> Tensor:
        """(B, N, 3) metres -> model units."""
        return (points - self.origin) * self.scale

    def to_metres(self, points: Tensor) -> Tensor:
        """(B, ..., N, 3) model units -> metres."""
        origin = self.origin.reshape(self.origin.shape[0], *([1] * (points.dim() - 2)), 3)
        return points.float() / self.scale + origin


def compile_networks(module: nn.Module, mode: str) -> None:
    """torch.compile, in place, every DiT below `module`: the blocks whose ops repeat in every step and every
    denoising step. The point encoders stay eager (inductor, torch 2.10, fails on their dynamic shapes with a
    stride assertion), as do farthest point sampling and the Python-level control flow."""
    for sub in module.modules():
        if isinstance(sub, DiT):
            sub.compile(mode=mode)


class TaxDPDPolicy(CheckedLoading, EmaWeights, PreTrainedPolicy):
    """Goal predictor for object placement: samples where every object point must go.

    Public API (metres, caller's frame): `sample_goals`, `predict_poses`, `placement_distribution`.
    `select_action` returns one goal cloud per batch element, so the policy also runs under `lerobot-eval`.
    """

    config_class = TaxDPDConfig
    name = "taxdpd"
    ZERO_START_MODULES = {"position_octaves": ".local_stage.denoiser.positions."}  # model/positions.py

    def __init__(self, config: TaxDPDConfig, dataset_stats=None, dataset_meta=None, **kwargs) -> None:
        super().__init__(config)
        config.validate_features()
        warn_if_amp_is_slow(config)
        if config.point_scale is None and dataset_meta is not None:
            config.point_scale = estimate_point_scale(dataset_meta.root, config.object_scale)
        # Whether the training data's object and scene clouds are in FPS order (the dataset's metadata says so):
        # their encoder layouts are then prefixes, with no FPS in the step. A property of the data, not saved.
        recorded = read_point_order(dataset_meta.root) if dataset_meta is not None else {}
        self.training_clouds_fps_ordered = (recorded.get(OBJECT_KEY, False), recorded.get(SCENE_KEY, False))
        self.model = TaxDPDModel(config)
        self._init_ema()
        if config.compile_mode is not None:
            compile_networks(self, config.compile_mode)
        self.metrics: dict = {}
        self._warned_scale = False
        self._cast_model: tuple[tuple, nn.Module] | None = None
        self._unread_step: tuple[dict[str, Tensor], list[tuple[Tensor, Callable]]] | None = None

    # ------------------------------------------------------------------------------------ LeRobot hooks
    def reset(self) -> None:
        """Nothing to reset: each call predicts a goal from the current observation alone."""

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict[str, float]]:
        """Training loss and its terms. In training mode nothing here waits for the device: the clouds' values
        (NaN, overflow) and the loss terms are read back together at the end of the step, by `update()`, which
        lerobot-train calls after the optimiser (or by the next `forward`); until then the terms are tensors."""
        self._read_back_step()
        eager = not self.training
        object_points, scene_points = self._checked_inputs(
            batch.get(OBJECT_KEY), batch.get(SCENE_KEY), OBJECT_KEY, SCENE_KEY, check_values=eager
        )
        goal_points = self._checked_goal(batch.get(ACTION_KEY), object_points, check_values=eager)
        checks = []
        if not eager:
            for name, cloud in zip(CLOUD_KEYS, (object_points, scene_points, goal_points), strict=True):
                checks.append((value_faults(cloud), lambda values, name=name: raise_value_faults(name, *values)))
            if self.config.point_scale is not None:
                radius = object_radius(object_points).median().reshape(1).double()
                checks.append((radius, lambda values: self._warn_units(values[0], OBJECT_KEY)))
        fps_ordered, dense_scene = (False, False), scene_points
        if self.training:
            object_points, scene_points, goal_points, fps_ordered, dense_scene = self._augment(
                object_points, scene_points, goal_points
            )
        frame = ModelFrame.of_scene(scene_points, self._point_scale(object_points, OBJECT_KEY))
        with self._autocast():
            losses = self._training_call(
                frame.to_model(object_points),
                frame.to_model(scene_points),
                frame.to_model(goal_points),
                fps_ordered=fps_ordered,
                dense_scene=frame.to_model(dense_scene) if self.config.local_scene_points else None,
            )
        loss = losses.pop("loss")
        terms = {name: value.detach().float() for name, value in losses.items()}
        self._unread_step = (terms, checks)
        if eager:
            self._read_back_step()
        return loss, terms

    def update(self) -> None:
        """After each optimiser step (`lerobot-train` calls it): the weight average, then the step's read-back."""
        super().update()
        self._read_back_step()

    def _read_back_step(self) -> None:
        """One device-to-host transfer for the last `forward`: run its deferred input checks (which raise on
        bad clouds), then turn the loss terms it returned into floats, in the same dict."""
        if self._unread_step is None:
            return
        (terms, checks), self._unread_step = self._unread_step, None
        values = torch.cat([torch.stack(list(terms.values())).double(), *(t for t, _ in checks)]).tolist()
        start = len(terms)
        for tensor, check in checks:
            check(values[start : start + tensor.numel()])
            start += tensor.numel()
        terms.update(zip(terms, values[: len(terms)], strict=True))

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """`config.num_goal_samples` goal clouds per batch element: (B, K, N_O, 3)."""
        return self.sample_goals(batch[OBJECT_KEY], batch[SCENE_KEY], self.config.num_goal_samples)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], **kwargs) -> Tensor:
        """One goal cloud per batch element: (B, N_O, 3)."""
        return self.predict_action_chunk(batch)[:, 0]

    # -------------------------------------------------------------------------------------- public API
    @torch.no_grad()
    def sample_goals(
        self,
        object_points: Tensor,
        scene_points: Tensor,
        num_samples: int = 1,
        *,
        num_inference_steps: int | None = None,
        sampler: str | None = None,
        gmm_frames: str | None = None,
        frame_temperature: float | None = None,
        generator: torch.Generator | None = None,
        placement_frames=None,
    ) -> Tensor:
        """Sample goal clouds: object (B, N_O, 3), scene (B, N_S, 3) in metres -> (B, K, N_O, 3).

        Tensors or numpy arrays are accepted; the answer is a float32 tensor on the policy's device.
        Row i of each sample is where point i of the object should go. `num_inference_steps`, `sampler`
        ("ddim" or "ddpm"), `gmm_frames` ("components" or "modes", see `TaxDPDConfig.gmm_frames`) and
        `frame_temperature` (see `TaxDPDConfig.frame_temperature`) default to the config's; `generator` makes
        sampling reproducible.
        `placement_frames` (B, 3), metres: where the object's centroid goes, given instead of sampled from
        the Dense GMM, so the local stage alone is measured (e.g. at the true goal's centroid).
        """
        object_points, scene_points = self._checked_inputs(object_points, scene_points)
        return self._sample_checked(
            object_points,
            scene_points,
            num_samples,
            num_inference_steps=num_inference_steps,
            sampler=sampler,
            gmm_frames=gmm_frames,
            frame_temperature=frame_temperature,
            generator=generator,
            placement_frames=placement_frames,
        )

    def _sample_checked(
        self,
        object_points: Tensor,
        scene_points: Tensor,
        num_samples: int,
        *,
        num_inference_steps: int | None = None,
        sampler: str | None = None,
        gmm_frames: str | None = None,
        frame_temperature: float | None = None,
        generator: torch.Generator | None = None,
        placement_frames=None,
    ) -> Tensor:
        """`sample_goals` on clouds `_checked_inputs` returned: their values are read once per call, not twice."""
        if not isinstance(num_samples, numbers.Integral) or num_samples < 1:
            raise ValueError(f"num_samples: must be a positive integer, got {num_samples!r}")
        num_samples = int(num_samples)
        placement_frames = self._checked_frames(placement_frames, object_points)
        if generator is not None and not (
            isinstance(generator, torch.Generator) and generator.device.type == object_points.device.type
        ):
            raise TypeError(f"generator: expected a torch.Generator on {object_points.device}, got {generator!r}")
        steps = self.config.num_inference_steps if num_inference_steps is None else num_inference_steps
        check_inference_steps(steps, self.config.num_train_timesteps)
        sampler = self.config.sampler if sampler is None else sampler
        if not isinstance(sampler, str) or sampler not in SAMPLER_ETA:
            raise ValueError(f"sampler: must be one of {sorted(SAMPLER_ETA)}, got {sampler!r}")
        eta = SAMPLER_ETA[sampler]
        gmm_frames = self.config.gmm_frames if gmm_frames is None else gmm_frames
        if gmm_frames not in GMM_FRAMES:
            raise ValueError(f"gmm_frames: must be one of {list(GMM_FRAMES)}, got {gmm_frames!r}")
        frame_temperature = self.config.frame_temperature if frame_temperature is None else frame_temperature
        check_frame_temperature(frame_temperature, self.config.disentangled)
        model_object, model_scene, fps_ordered, radius = self._at_model_resolution(object_points, scene_points)
        frame = ModelFrame.of_scene(model_scene, self._point_scale(object_points, radius=radius))
        if placement_frames is not None:  # where the object's centroid goes -> where the model's subsample's goes
            shift = model_object.mean(1) - object_points.mean(1)
            placement_frames = frame.to_model((placement_frames + shift).unsqueeze(1)).squeeze(1)
        with self._autocast():
            goals = self._sampling_model().sample(
                frame.to_model(model_object),
                frame.to_model(model_scene),
                num_samples,
                steps,
                eta=eta,
                generator=generator,
                frames=placement_frames,
                fps_ordered=fps_ordered,
                dense_scene=frame.to_model(scene_points) if self.config.local_scene_points else None,
                gmm_frames=gmm_frames,
                frame_temperature=frame_temperature,
            )
        goals = frame.to_metres(goals)
        if model_object.shape[1] != object_points.shape[1]:
            goals = lift_point_motion(object_points, model_object, goals)
        return goals

    @torch.no_grad()
    def predict_poses(
        self, object_points: Tensor, scene_points: Tensor, num_samples: int = 1, **sample_kwargs
    ) -> Tensor:
        """SE(3) goal poses T (B, K, 4, 4) with goal = T @ object, fitted to sampled goals by RANSAC-SVD."""
        object_points, scene_points = self._checked_inputs(object_points, scene_points)
        goals = self._sample_checked(object_points, scene_points, num_samples, **sample_kwargs)
        source = object_points.unsqueeze(1).expand_as(goals)
        transforms, _ = estimate_rigid_transform(
            source,
            goals,
            threshold=self.config.ransac_threshold,
            num_hypotheses=self.config.ransac_hypotheses,
            generator=sample_kwargs.get("generator"),
        )
        return transforms.float()

    @torch.no_grad()
    def placement_distribution(self, object_points: Tensor, scene_points: Tensor) -> tuple[Tensor, Tensor]:
        """The Dense GMM: mixing weights (B, N_S) over scene points and component means (B, N_S, 3), metres."""
        object_points, scene_points = self._checked_inputs(object_points, scene_points)
        model_object, model_scene, _, radius = self._at_model_resolution(object_points, scene_points)
        frame = ModelFrame.of_scene(model_scene, self._point_scale(object_points, radius=radius))
        with self._autocast():
            weights, means = self.inference_model.placement_distribution(
                frame.to_model(model_object), frame.to_model(model_scene)
            )
        weights, means = weights.float(), frame.to_metres(means)
        if model_scene.shape[1] != scene_points.shape[1]:
            # Each component of the reduced scene stands for the input points nearest to it: they share its
            # mean and split its weight, so the answer keeps one entry per input scene point and sums to one.
            nearest = nearest_indices(scene_points, model_scene).squeeze(-1)  # (B, N_S)
            counts = torch.zeros_like(weights).scatter_add_(1, nearest, torch.ones_like(nearest, dtype=weights.dtype))
            weights = weights.gather(1, nearest) / counts.gather(1, nearest)
            means = gather_points(means, nearest)
        return weights, means

    # ---------------------------------------------------------------------------------------- helpers
    def _sampling_model(self) -> nn.Module:
        """The inference model; under AMP, a copy whose linear layers hold bf16 weights, made once per change of
        the weights. Autocast caches its casts only for weights that require grad, so it would cast every weight
        again at every denoising step (2,200 casts of 7,900 ops for K = 10 at the paper's size)."""
        model = self.inference_model
        if not self.config.use_amp:
            return model
        key = (id(model), tuple((p.data_ptr(), p._version) for p in model.parameters()))
        if self._cast_model is None or self._cast_model[0] != key:
            cast = copy.deepcopy(model)
            for module in cast.modules():
                if isinstance(module, nn.Linear):
                    module.to(torch.bfloat16)
            if cast.local_stage.denoiser.frame_token is not None:  # joins the bf16 tokens at every step
                cast.local_stage.denoiser.frame_token.data = cast.local_stage.denoiser.frame_token.data.bfloat16()
            if self.config.compile_mode is not None:
                compile_networks(cast, self.config.compile_mode)
            self._cast_model = (key, cast)  # a tuple: not registered as a submodule, never saved
        return self._cast_model[1]

    def _training_call(self, *args, **kwargs) -> dict[str, Tensor]:
        """The model's losses; under AMP with gradients on, its linear layers cast to bf16 together
        (`call_with_linears_cast`: the same step, with four casts in all instead of four a layer)."""
        if self.config.use_amp and torch.is_grad_enabled():
            return call_with_linears_cast(self.model, torch.bfloat16, *args, **kwargs)
        return self.model(*args, **kwargs)

    def _autocast(self):
        if not self.config.use_amp:
            return contextlib.nullcontext()
        return torch.autocast(device_type=next(self.parameters()).device.type, dtype=torch.bfloat16)

    def _at_model_resolution(
        self, object_points: Tensor, scene_points: Tensor
    ) -> tuple[Tensor, Tensor, tuple[bool, bool], float]:
        """The clouds at the network's point counts, whether each is in FPS order from its point 0 (its layout is
        then free), and the objects' median radius in metres.

        A cloud whose first points are its FPS from point 0 (every cloud this project records is in that order:
        `is_farthest_point_prefix` checks it in a few parallel ops) is cut to them; any other cloud larger than
        the network's count is reduced by FPS from point 0, the same points. The check's answers and the radius
        come back from the device in one read. The network is trained at `num_*_points`; feeding it denser
        clouds would change every PointNet++ neighbourhood and cost attention quadratically, so inference sees
        the same resolution as training.
        """
        clouds = [object_points, scene_points]
        sizes = [
            min(self.config.num_object_points, object_points.shape[1]),
            min(self.config.num_scene_points, scene_points.shape[1]),
        ]
        answers = [object_radius(object_points.double()).median().reshape(1)]
        answers += [
            is_farthest_point_prefix(cloud.float(), size).all().reshape(1).double()
            for cloud, size in zip(clouds, sizes, strict=True)
        ]
        radius, *in_order = torch.cat(answers).tolist()
        ordered = [bool(answer) for answer in in_order]
        unordered = [i for i, cloud in enumerate(clouds) if not ordered[i] and cloud.shape[1] > sizes[i]]
        if unordered:
            picked = farthest_point_sample_parts([clouds[i].float() for i in unordered], [sizes[i] for i in unordered])
            for i, keep in zip(unordered, picked, strict=True):
                clouds[i] = gather_points(clouds[i], keep)
        clouds = [
            cloud[:, :size] if is_ordered else cloud
            for cloud, size, is_ordered in zip(clouds, sizes, ordered, strict=True)
        ]
        fps_ordered = tuple(ordered[i] or i in unordered for i in range(2))
        return clouds[0], clouds[1], fps_ordered, radius

    def _reduced(self, object_points: Tensor, scene_points: Tensor) -> tuple[list[Tensor], list[Tensor | None]]:
        """Object and scene, each larger than the network's point count reduced by FPS from random starts (one
        pass for both; an augmentation); the indices each kept (None: whole)."""
        clouds = [object_points, scene_points]
        sizes = [self.config.num_object_points, self.config.num_scene_points]
        keeps: list[Tensor | None] = [None, None]
        reduced = [i for i, cloud in enumerate(clouds) if cloud.shape[1] > sizes[i]]
        if reduced:
            picked = downsample_indices([clouds[i] for i in reduced], [sizes[i] for i in reduced])
            for i, keep in zip(reduced, picked, strict=True):
                clouds[i], keeps[i] = gather_points(clouds[i], keep), keep
        return clouds, keeps

    def _point_scale(self, object_points: Tensor, name: str = "object_points", radius: float | None = None) -> float:
        """Model units per metre; `radius`: the objects' median radius, when the caller has read it already."""
        if radius is None and (self.config.point_scale is None or not self.training):
            radius = float(object_radius(object_points.double()).median())
        if self.config.point_scale is not None:
            if not self.training:  # a training step checks the units at its read-back
                self._warn_units(radius, name)
            return self.config.point_scale
        if not self._warned_scale:
            logger.warning(
                "config.point_scale is unset (no training dataset was given): scaling by this batch's median "
                "object radius. Set point_scale or train on a dataset to fix it."
            )
            self._warned_scale = True
        return self.config.object_scale / max(radius, 1e-9)

    def _warn_units(self, radius: float, name: str) -> None:
        """Warn when the objects (median radius, metres) are far larger or smaller than the ones this checkpoint
        was trained on: the model sees every input multiplied by `point_scale`, so wrong units give confident
        garbage."""
        trained = self.config.object_scale / self.config.point_scale  # median training object radius, metres
        ratio = radius / trained
        if 1 / SCALE_TOLERANCE <= ratio <= SCALE_TOLERANCE:
            return
        hint = (
            "; these look like millimetres: divide the clouds by 1000"
            if 300 <= ratio <= 3000
            else "; check the units of both clouds"
        )
        warnings.warn(
            f"{name}: the object's radius is {radius:.4g}, {ratio:.3g}x the {trained:.3g} m of the objects this "
            f"model was trained on (config.point_scale = {self.config.point_scale:.4g} model units per metre); "
            f"inputs must be in metres{hint}",
            UserWarning,
            stacklevel=2,
        )

    def _checked_inputs(
        self,
        object_points,
        scene_points,
        object_name: str = "object_points",
        scene_name: str = "scene_points",
        check_values: bool = True,
    ) -> tuple[Tensor, Tensor]:
        checked = []
        for value, name in ((object_points, object_name), (scene_points, scene_name)):
            if value is None:
                raise PointCloudError(f"{name}: missing")
            if isinstance(value, (np.ndarray, Tensor)) and value.ndim == 2:
                raise PointCloudError(
                    f"{name}: expected a batch (B, N, 3), got {tuple(value.shape)}; add one with [None]"
                )
            check_point_cloud(value, name, min_points=3, batched=True, check_values=False)
            if value.ndim != 3 or value.shape[0] == 0:
                raise PointCloudError(f"{name}: expected shape (B, N, 3) with B >= 1, got {tuple(value.shape)}")
            checked.append(value)
        if check_values:
            check_values_together({object_name: checked[0], scene_name: checked[1]})
        object_points, scene_points = (
            torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)) if isinstance(v, np.ndarray) else v
            for v in checked  # numpy of any byte order or strides; checked above, so float
        )
        if object_points.shape[0] != scene_points.shape[0]:
            raise PointCloudError(
                f"{object_name} and {scene_name}: batch sizes {object_points.shape[0]} and "
                f"{scene_points.shape[0]} differ"
            )
        device = next(self.parameters()).device
        return object_points.to(device, torch.float32), scene_points.to(device, torch.float32)

    def _checked_frames(self, placement_frames, object_points: Tensor) -> Tensor | None:
        if placement_frames is None:
            return None
        frames = torch.as_tensor(placement_frames)
        if frames.shape != (object_points.shape[0], 3):
            raise PointCloudError(
                f"placement_frames: expected shape ({object_points.shape[0]}, 3), one per scene, got "
                f"{tuple(frames.shape)}"
            )
        if not torch.isfinite(frames).all():
            raise PointCloudError("placement_frames: NaN or infinite coordinates")
        return frames.to(object_points)

    def _checked_goal(self, goal_points, object_points: Tensor, check_values: bool = True) -> Tensor:
        if goal_points is None:
            raise PointCloudError(f"{ACTION_KEY}: missing (the goal cloud is the training target)")
        check_point_cloud(goal_points, ACTION_KEY, min_points=3, batched=True, check_values=check_values)
        check_same_shape(object_points, goal_points, OBJECT_KEY, ACTION_KEY)
        return goal_points.to(object_points)

    def _augment(
        self, object_points: Tensor, scene_points: Tensor, goal_points: Tensor
    ) -> tuple[Tensor, Tensor, Tensor, tuple[bool, bool], Tensor]:
        """The training batch's augmentations; last, each cloud larger than the network's point count reduced by
        FPS, which leaves it in FPS order (the returned flags, for object and scene), so its layout is free; a
        cloud the dataset recorded in FPS order keeps it through the rigid augmentations, not through a cut.
        Also returns the scene before its reduction, where a local stage takes its local scene from."""
        config = self.config
        if config.z_rotation_augmentation:
            object_points, scene_points, goal_points = random_z_rotation(
                object_points, scene_points, goal_points, config.z_rotation_range
            )
        if config.start_yaw_range > 0 or config.start_tilt_range > 0:
            object_points = random_start_pose(object_points, config.start_yaw_range, config.start_tilt_range)
        if config.object_occlusion_prob > 0:
            keep = plane_cut(object_points, config.object_occlusion_prob)
            object_points, goal_points = gather_points(object_points, keep), gather_points(goal_points, keep)
        if config.scene_occlusion_prob > 0:
            scene_points = gather_points(scene_points, ball_cut(scene_points, config.scene_occlusion_prob))
        (model_object, model_scene), (object_keep, scene_keep) = self._reduced(object_points, scene_points)
        if object_keep is not None:
            goal_points = gather_points(goal_points, object_keep)
        object_recorded, scene_recorded = self.training_clouds_fps_ordered
        fps_ordered = (
            object_keep is not None or (object_recorded and config.object_occlusion_prob == 0),
            scene_keep is not None or (scene_recorded and config.scene_occlusion_prob == 0),
        )
        return model_object, model_scene, goal_points, fps_ordered, scene_points

    # ------------------------------------------------------------------------------ saving and loading
    def _save_pretrained(self, save_directory: Path) -> None:
        super()._save_pretrained(save_directory)
        save_metrics(self.metrics, save_directory)
        self.generate_model_card(None, self.name, self.config.license, self.config.tags).save(
            str(Path(save_directory) / "README.md")
        )

    @classmethod
    def from_pretrained(cls, pretrained_name_or_path, **kwargs):
        policy = super().from_pretrained(pretrained_name_or_path, **kwargs)
        policy.metrics = load_metrics(pretrained_name_or_path, kwargs)
        return policy

    def generate_model_card(self, dataset_repo_id, model_type, license, tags) -> ModelCard:
        return render_model_card(self.config, self.metrics, dataset_repo_id, license, tags)
