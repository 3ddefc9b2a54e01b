"""DiT blocks with adaLN-Zero conditioning, self-attention over tokens and cross-attention to a context.

Both stages use them: the local denoiser's object (+ frame) tokens attend to scene tokens; the Dense GMM's
scene tokens attend to object tokens. LayerNorms carry no affine parameters (eps 1e-6); modulation and
output layers start at zero so every block starts as the identity.

What every block derives from the inputs they share (the normalised context's keys and values, the
modulation from the condition) the `DiT` computes for all blocks at once, one matrix product each with the
blocks' weights side by side: the same values for a handful of kernel launches instead of a handful a block.
For the same reason the `1 +` of every modulation's scale is added once for all blocks, and while sampling each
modulation and gated residual is one fused multiply-add (`addcmul`) instead of two elementwise ops.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def _norm(dim: int) -> nn.LayerNorm:
    return nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)


def _multiply_add(x: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """x + a * b: one fused launch (`addcmul`) where no gradient is recorded (sampling); under autograd a
    product and a sum, whose backward launches two products fewer than addcmul's."""
    if torch.is_grad_enabled():
        return x + a * b
    return torch.addcmul(x, a, b)


def _modulate(x: Tensor, shift: Tensor, one_plus_scale: Tensor) -> Tensor:
    """x * (1 + scale) + shift for tokens x (B, T, dim), given 1 + scale (B, dim)."""
    return _multiply_add(shift.unsqueeze(1), x, one_plus_scale.unsqueeze(1))


def _gated(x: Tensor, gate: Tensor, update: Tensor) -> Tensor:
    """x + gate * update, gate (B, dim)."""
    return _multiply_add(x, gate.unsqueeze(1), update)


#: Where a block's modulation holds scales: (shift, scale, gate) for self-attention, cross-attention, MLP.
_SCALE_CHUNKS = (1, 4, 7)


def _scale_offset(dim: int) -> Tensor:
    """Ones at a block's scale entries, zeros elsewhere: the modulation plus this gives 1 + scale."""
    offset = torch.zeros(9, dim)
    offset[list(_SCALE_CHUNKS)] = 1.0
    return offset.flatten()


class TimestepEmbedding(nn.Module):
    """Sinusoidal embedding of the diffusion step followed by an MLP."""

    def __init__(self, dim: int, frequency_dim: int = 256) -> None:
        super().__init__()
        self.frequency_dim = frequency_dim
        self.mlp = nn.Sequential(nn.Linear(frequency_dim, dim), nn.SiLU(), nn.Linear(dim, dim))

    def forward(self, t: Tensor) -> Tensor:
        half = self.frequency_dim // 2
        freqs = torch.exp(-math.log(10_000.0) * torch.arange(half, device=t.device, dtype=torch.float32) / half)
        angles = t.float().unsqueeze(-1) * freqs
        return self.mlp(torch.cat([torch.cos(angles), torch.sin(angles)], -1))


class Attention(nn.Module):
    """Multi-head attention through `scaled_dot_product_attention` (fused kernels on CPU and GPU)."""

    def __init__(self, dim: int, num_heads: int) -> None:
        super().__init__()
        self.num_heads = num_heads
        self.query = nn.Linear(dim, dim)
        self.key_value = nn.Linear(dim, 2 * dim)
        self.out = nn.Linear(dim, dim)

    def _heads(self, x: Tensor) -> Tensor:
        b, n, d = x.shape
        return x.view(b, n, self.num_heads, d // self.num_heads).transpose(1, 2)

    def forward(self, x: Tensor, context: Tensor) -> Tensor:
        return self.attend(x, self.key_value(context))

    def attend(self, x: Tensor, keys_values: Tensor) -> Tensor:
        """Attention of `x` to a context whose projection `key_value(context)` is given."""
        q = self._heads(self.query(x))
        k, v = (self._heads(t) for t in keys_values.chunk(2, dim=-1))
        attended = F.scaled_dot_product_attention(q, k, v)
        return self.out(attended.transpose(1, 2).reshape(x.shape))


class DiTBlock(nn.Module):
    """x += gate * SelfAttn(mod(LN x)); x += gate * CrossAttn(mod(LN x), LN ctx); x += gate * MLP(mod(LN x)).

    Its modulation (`modulation_of(condition)`, the scales with 1 added) and the context's keys and values
    (`cross_attention.key_value(LN ctx)`) come from the `DiT`, which computes them for all its blocks together."""

    def __init__(self, dim: int, num_heads: int, mlp_ratio: float) -> None:
        super().__init__()
        hidden = int(dim * mlp_ratio)
        self.norm_self, self.norm_cross, self.norm_mlp = _norm(dim), _norm(dim), _norm(dim)
        self.self_attention = Attention(dim, num_heads)
        self.cross_attention = Attention(dim, num_heads)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(approximate="tanh"), nn.Linear(hidden, dim))
        self.modulation = nn.Sequential(nn.SiLU(), nn.Linear(dim, 9 * dim))
        nn.init.zeros_(self.modulation[-1].weight)
        nn.init.zeros_(self.modulation[-1].bias)
        self.register_buffer("scale_offset", _scale_offset(dim), persistent=False)

    def modulation_of(self, condition: Tensor) -> Tensor:
        """The block's nine modulation vectors side by side, each scale as 1 + scale."""
        modulation = self.modulation(condition)
        return modulation + self.scale_offset.to(modulation.dtype)

    def forward(self, x: Tensor, context_keys_values: Tensor, modulation: Tensor) -> Tensor:
        (s1, c1, g1, s2, c2, g2, s3, c3, g3) = modulation.chunk(9, dim=-1)
        h = _modulate(self.norm_self(x), s1, c1)
        x = _gated(x, g1, self.self_attention(h, h))
        h = _modulate(self.norm_cross(x), s2, c2)
        x = _gated(x, g2, self.cross_attention.attend(h, context_keys_values))
        return _gated(x, g3, self.mlp(_modulate(self.norm_mlp(x), s3, c3)))


class OutputHead(nn.Module):
    """adaLN-modulated LayerNorm and a zero-initialised linear read-out."""

    def __init__(self, dim: int, out_dim: int) -> None:
        super().__init__()
        self.norm = _norm(dim)
        self.modulation = nn.Sequential(nn.SiLU(), nn.Linear(dim, 2 * dim))
        self.linear = nn.Linear(dim, out_dim)
        for layer in (self.modulation[-1], self.linear):
            nn.init.zeros_(layer.weight)
            nn.init.zeros_(layer.bias)

    def modulation_of(self, condition: Tensor) -> tuple[Tensor, Tensor]:
        """Shift and 1 + scale, each (B, dim)."""
        shift, scale = self.modulation(condition).chunk(2, dim=-1)
        return shift, 1.0 + scale

    def forward(
        self, x: Tensor, condition: Tensor | None = None, *, modulation: tuple[Tensor, Tensor] | None = None
    ) -> Tensor:
        """Read-out of tokens x under `condition`, or under its `modulation_of` computed beforehand."""
        shift, one_plus_scale = self.modulation_of(condition) if modulation is None else modulation
        return self.linear(_modulate(self.norm(x), shift, one_plus_scale))


class DiT(nn.Module):
    """A stack of `DiTBlock`s over tokens (B, T, dim) attending to a context (B, C, dim)."""

    def __init__(self, dim: int, num_heads: int, num_blocks: int, mlp_ratio: float) -> None:
        super().__init__()
        self.blocks = nn.ModuleList(DiTBlock(dim, num_heads, mlp_ratio) for _ in range(num_blocks))
        self.norm_context = _norm(dim)
        self.register_buffer("scale_offset", _scale_offset(dim).repeat(num_blocks), persistent=False)

    def modulations_of(self, condition: Tensor) -> Tensor:
        """Every block's modulation side by side, (B, blocks * 9 * dim), each scale as 1 + scale."""
        modulations = linear_together([b.modulation[-1] for b in self.blocks], F.silu(condition))
        return modulations + self.scale_offset.to(modulations.dtype)

    def forward(
        self, tokens: Tensor, context: Tensor, condition: Tensor | None = None, *, modulations: Tensor | None = None
    ) -> Tensor:
        """Tokens after every block, under `condition` or under its `modulations_of` computed beforehand (a
        sampling loop computes those of all its timesteps at once)."""
        blocks = len(self.blocks)
        if modulations is None:
            modulations = self.modulations_of(condition)
        modulations = modulations.chunk(blocks, -1)
        keys_values = linear_together(
            [b.cross_attention.key_value for b in self.blocks], self.norm_context(context)
        ).chunk(blocks, -1)
        for block, block_keys_values, modulation in zip(self.blocks, keys_values, modulations, strict=True):
            tokens = block(tokens, block_keys_values, modulation)
        return tokens


def linear_together(layers: list[nn.Linear], x: Tensor) -> Tensor:
    """`torch.cat([layer(x) for layer in layers], -1)` as one matrix product."""
    if len(layers) == 1:
        return layers[0](x)
    weight = torch.cat([layer.weight for layer in layers])
    bias = torch.cat([layer.bias for layer in layers])
    return F.linear(x, weight, bias)
