"""Fourier features of token positions, for the local stage's tokens.

A network that takes coordinates only through linear layers (the point encoders' first layers, the feature
propagation's skip of xyz) learns functions that vary slowly in space first, and precise placement is a
function that varies fast: where a slot's centre lies to a few millimetres between two neighbours. Sines and
cosines of the coordinates at octave frequencies hand the attention positions it can compare at every scale
(the encoding NeRF and Perceiver give their coordinates). The projection starts at zero, so a model with the
encoding starts as the one without it.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

#: The lowest frequency, per model unit (an object's radius is `TaxDPDConfig.object_scale` = 3 units): a period
#: of 12.6 units spans a scene; each octave halves the period.
BASE_FREQUENCY = 0.5


class FourierPositions(nn.Module):
    """xyz (..., 3) in model units -> (..., dim): sin and cos of each coordinate at `octaves` frequencies,
    projected to `dim` by a linear layer initialised to zero."""

    def __init__(self, dim: int, octaves: int) -> None:
        super().__init__()
        frequencies = BASE_FREQUENCY * 2.0 ** torch.arange(octaves, dtype=torch.float32)
        self.register_buffer("frequencies", frequencies, persistent=False)
        self.projection = nn.Linear(6 * octaves, dim)
        nn.init.zeros_(self.projection.weight)
        nn.init.zeros_(self.projection.bias)

    def forward(self, xyz: Tensor) -> Tensor:
        angles = (xyz.float().unsqueeze(-1) * self.frequencies).flatten(-2)
        return self.projection(torch.cat([angles.sin(), angles.cos()], -1))
