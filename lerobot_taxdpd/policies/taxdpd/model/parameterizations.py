"""How the local stage represents a goal cloud in the placement frame g, one class per ablation.

A parameterization maps a goal cloud to the variables that are diffused (`encode`), composes the current
goal estimate back from them (`compose`), says how to noise them (`sample_noise`), and reads the
denoiser's outputs as predicted noise (`split`). The scheduler treats every variable alike.

- `DisentangledPoints` (TAX-DPD): a frame rho (B, 1, 3) = goal centroid and a zero-mean shape phi (B, N, 3).
- `JointPoints` ("w/o disentangled point diffusion"): the goal points (B, N, 3) diffused as one variable.
- `SE3Pose` ("w/ SE(3) diffusion"): the frame plus a 6-D rotation (B, 1, 6) applied to the initial object.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from lerobot_taxdpd.maths.geometry import (
    fit_rigid_transform,
    matrix_to_rotation_6d,
    random_axis_angle_rotation,
    rotation_6d_to_matrix,
)

State = dict[str, Tensor]


def randn_like(x: Tensor, generator: torch.Generator | None = None) -> Tensor:
    """Standard normal noise shaped like `x`, drawn from `generator` (on its own device) when given."""
    device = generator.device if generator is not None else x.device
    return torch.randn(x.shape, generator=generator, device=device, dtype=x.dtype).to(x.device)


def _centre(x: Tensor) -> Tensor:
    return x - x.mean(dim=1, keepdim=True)


def _turned(shape: Tensor, std: float | Tensor, generator: torch.Generator | None) -> Tensor:
    """R phi for a random rotation R per sample (axis uniform on S^2, angle ~ N(0, std^2); std may be (B,))."""
    device = generator.device if generator is not None else shape.device
    if isinstance(std, Tensor):
        std = std.to(device)
    rotation = random_axis_angle_rotation(shape.shape[0], std, generator=generator, device=device, dtype=shape.dtype)
    return shape @ rotation.to(shape.device).transpose(-1, -2)


def _rotation_noise(shape: Tensor, std: float, generator: torch.Generator | None) -> Tensor:
    """R phi - phi: the paper's rotation noise, added to the Gaussian noise of the shape."""
    return _turned(shape, std, generator) - shape


class DisentangledPoints:
    frame_dim = 3
    has_point_output = True

    def __init__(self, frame_weight: float = 1.0, frame_from_points: bool = False) -> None:
        self.frame_weight = frame_weight
        self.frame_from_points = frame_from_points  # TaxDPDConfig.frame_from_points

    def encode(self, goal: Tensor, object_centred: Tensor) -> State:
        frame = goal.mean(dim=1, keepdim=True)
        return {"frame": frame, "shape": goal - frame}

    def sample_noise(self, clean: State, rotation_std: float, generator=None) -> State:
        shape_noise = _centre(randn_like(clean["shape"], generator))
        if rotation_std > 0:
            shape_noise = shape_noise + _rotation_noise(clean["shape"], rotation_std, generator)
        return {"frame": randn_like(clean["frame"], generator), "shape": shape_noise}

    def turn_shape(self, clean: State, std: Tensor, generator=None) -> State:
        """The clean goal with its shape turned about its centroid by a random rotation (angle std per sample)."""
        return {"frame": clean["frame"], "shape": _turned(clean["shape"], std, generator)}

    def initial_state(self, object_centred: Tensor, generator=None) -> State:
        return self.project(
            {"frame": randn_like(object_centred[:, :1], generator), "shape": randn_like(object_centred, generator)}
        )

    def project(self, state: State) -> State:
        return {"frame": state["frame"], "shape": _centre(state["shape"])}

    def compose(self, state: State, object_centred: Tensor) -> tuple[Tensor, Tensor]:
        return state["shape"] + state["frame"], state["shape"]

    def split(self, point_out: Tensor | None, frame_out: Tensor | None) -> State:
        # Centred in fp32 without a cast of its own: the mean accumulates in fp32 and the difference promotes.
        mean = point_out.mean(1, keepdim=True, dtype=torch.float32)
        frame = frame_out.unsqueeze(1) + mean if self.frame_from_points else frame_out.unsqueeze(1)
        return {"frame": frame, "shape": point_out - mean}

    def centred_shape(self, state: State) -> Tensor:
        return state["shape"]

    def loss(self, predicted: State, target: State) -> dict[str, Tensor]:
        frame = F.mse_loss(predicted["frame"], target["frame"])
        shape = F.mse_loss(predicted["shape"], target["shape"])
        return {"loss_local": 0.5 * self.frame_weight * frame + 0.5 * shape, "loss_frame": frame, "loss_shape": shape}


class JointPoints:
    frame_dim = None
    has_point_output = True

    def encode(self, goal: Tensor, object_centred: Tensor) -> State:
        return {"points": goal}

    def sample_noise(self, clean: State, rotation_std: float, generator=None) -> State:
        noise = randn_like(clean["points"], generator)
        if rotation_std > 0:
            noise = noise + _rotation_noise(_centre(clean["points"]), rotation_std, generator)
        return {"points": noise}

    def turn_shape(self, clean: State, std: Tensor, generator=None) -> State:
        centroid = clean["points"].mean(dim=1, keepdim=True)
        return {"points": _turned(clean["points"] - centroid, std, generator) + centroid}

    def initial_state(self, object_centred: Tensor, generator=None) -> State:
        return {"points": randn_like(object_centred, generator)}

    def project(self, state: State) -> State:
        return state

    def compose(self, state: State, object_centred: Tensor) -> tuple[Tensor, Tensor]:
        return state["points"], _centre(state["points"])

    def split(self, point_out: Tensor | None, frame_out: Tensor | None) -> State:
        return {"points": point_out.float()}

    def centred_shape(self, state: State) -> Tensor:
        return _centre(state["points"])

    def loss(self, predicted: State, target: State) -> dict[str, Tensor]:
        points = F.mse_loss(predicted["points"], target["points"])
        return {"loss_local": points, "loss_points": points}


class SE3Pose:
    frame_dim = 9
    has_point_output = False

    def __init__(self, frame_weight: float = 1.0) -> None:
        self.frame_weight = frame_weight

    def encode(self, goal: Tensor, object_centred: Tensor) -> State:
        frame = goal.mean(dim=1, keepdim=True)
        rotation = fit_rigid_transform(object_centred, goal - frame)[..., :3, :3]
        return {"frame": frame, "rotation": matrix_to_rotation_6d(rotation).unsqueeze(1)}

    def sample_noise(self, clean: State, rotation_std: float, generator=None) -> State:
        return {k: randn_like(v, generator) for k, v in clean.items()}

    def turn_shape(self, clean: State, std: Tensor, generator=None) -> State:
        """No rotation noise here: the 6-D rotation is diffused as it is (the paper's SE(3) ablation)."""
        return clean

    def initial_state(self, object_centred: Tensor, generator=None) -> State:
        frame = randn_like(object_centred[:, :1], generator)
        rotation = randn_like(object_centred.new_empty(object_centred.shape[0], 1, 6), generator)
        return {"frame": frame, "rotation": rotation}

    def project(self, state: State) -> State:
        return state

    def compose(self, state: State, object_centred: Tensor) -> tuple[Tensor, Tensor]:
        rotation = rotation_6d_to_matrix(state["rotation"][:, 0])
        shape = object_centred @ rotation.transpose(-1, -2)
        return shape + state["frame"], shape

    def split(self, point_out: Tensor | None, frame_out: Tensor | None) -> State:
        return {"frame": frame_out[:, None, :3], "rotation": frame_out[:, None, 3:]}

    def loss(self, predicted: State, target: State) -> dict[str, Tensor]:
        frame = F.mse_loss(predicted["frame"], target["frame"])
        rotation = F.mse_loss(predicted["rotation"], target["rotation"])
        return {
            "loss_local": 0.5 * self.frame_weight * frame + 0.5 * rotation,
            "loss_frame": frame,
            "loss_rotation": rotation,
        }


def make_parameterization(config) -> DisentangledPoints | JointPoints | SE3Pose:
    if config.local_diffusion == "se3":
        return SE3Pose(config.frame_loss_weight)
    if not config.disentangled:
        return JointPoints()
    return DisentangledPoints(config.frame_loss_weight, config.frame_from_points)
