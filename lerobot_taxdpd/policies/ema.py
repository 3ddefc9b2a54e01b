"""An exponential moving average of a policy's weights, shared by the goal predictor and the executor.

Diffusion policies sample from the averaged weights because the last iterate of a small-batch run is a
noisy point near the optimum, and every sampling step compounds that noise (DP3 and Diffusion Policy both
do this). The decay warms up as DP3's does, so early, poor weights are forgotten quickly.
"""

from __future__ import annotations

import copy

import torch
from torch import nn


def ema_decay(step: int, power: float, max_decay: float) -> float:
    """DP3's warm-up decay after `step` updates: 1 - (1 + step) ** -power, capped at `max_decay`."""
    return min(max_decay, max(0.0, 1.0 - (1.0 + step) ** -power))


@torch.no_grad()
def update_ema(average: nn.Module, model: nn.Module, step: int, power: float, max_decay: float) -> None:
    """Move every parameter and floating buffer of `average` towards `model`'s by the decay at `step`.

    One multi-tensor op for all of them (on a GPU a handful of launches, not one per tensor)."""
    weight = 1.0 - ema_decay(step, power, max_decay)
    pairs = list(zip(average.parameters(), model.parameters(), strict=True))
    pairs += [(a, c) for a, c in zip(average.buffers(), model.buffers(), strict=True) if a.is_floating_point()]
    torch._foreach_lerp_([a for a, _ in pairs], [c for _, c in pairs], weight)
    for averaged, current in zip(average.buffers(), model.buffers(), strict=True):
        if not averaged.is_floating_point():
            averaged.copy_(current)


class EmaWeights:
    """Mixin for a policy whose network is `self.model` and whose config has `use_ema`, `ema_power` and
    `ema_max_decay`: keeps the average in `self.ema_model` (saved with the checkpoint, so training resumes
    with it) and samples from it."""

    def _init_ema(self) -> None:
        """Call once `self.model` exists."""
        if self.config.use_ema:
            self.ema_model = copy.deepcopy(self.model).requires_grad_(False)
            self.register_buffer("ema_step", torch.zeros((), dtype=torch.long))
            # The decay depends on the step; reading the step buffer back every update would make the host wait
            # for the device, so the host keeps its own count, re-read once after weights are loaded.
            self._ema_host_step: int | None = None
            self.register_load_state_dict_post_hook(EmaWeights._forget_host_step)

    @staticmethod
    def _forget_host_step(module, _incompatible_keys) -> None:
        module._ema_host_step = None

    @property
    def inference_model(self) -> nn.Module:
        """The weights the policy acts with: the average's when the config keeps one."""
        return self.ema_model if self.config.use_ema else self.model

    def get_optim_params(self):
        return self.model.parameters()

    def update(self) -> None:
        """After each optimiser step (`lerobot-train` calls it): move the average towards the trained weights."""
        if not self.config.use_ema:
            return
        if self._ema_host_step is None:
            self._ema_host_step = int(self.ema_step)
        update_ema(self.ema_model, self.model, self._ema_host_step, self.config.ema_power, self.config.ema_max_decay)
        self.ema_step += 1
        self._ema_host_step += 1

    def without_ema(self):
        """The same policy whose trained weights are the averaged ones it acts with, without the average:
        half the size to ship, the same actions."""
        if not self.config.use_ema:
            return self
        config = copy.deepcopy(self.config)
        config.use_ema = False
        plain = type(self)(config)
        plain.model.load_state_dict(self.ema_model.state_dict())
        plain.metrics = dict(self.metrics)
        return plain
