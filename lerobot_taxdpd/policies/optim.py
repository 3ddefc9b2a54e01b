"""AdamW that updates all parameters in one fused kernel, as an optimizer type LeRobot can build and resume.

LeRobot's `AdamWConfig` builds torch's AdamW with its defaults, which on the CPU is the single-tensor loop:
about ten ops and one host sync (`step.item()`) per parameter tensor, 3,300 ops and 364 syncs a step at the
paper's size. The fused implementation (CPU and CUDA) does the same update in one op per step.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
from lerobot.optim.optimizers import AdamWConfig, OptimizerConfig

#: Devices whose parameters torch's fused AdamW can update; on others the multi-tensor (foreach) path is used.
FUSED_DEVICES = ("cpu", "cuda", "xpu", "mps")


@OptimizerConfig.register_subclass("fused_adamw")
@dataclass
class FusedAdamWConfig(AdamWConfig):
    """LeRobot's AdamW settings, built with `fused=True` where the parameters' device supports it."""

    def build(self, params) -> torch.optim.Optimizer:
        params = list(params)
        kwargs = asdict(self)
        kwargs.pop("grad_clip_norm")
        tensors = [p for group in params for p in group["params"]] if params and isinstance(params[0], dict) else params
        if all(p.device.type in FUSED_DEVICES for p in tensors):
            return torch.optim.AdamW(params, fused=True, **kwargs)
        return torch.optim.AdamW(params, foreach=True, **kwargs)
