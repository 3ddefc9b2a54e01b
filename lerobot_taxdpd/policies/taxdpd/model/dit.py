"""DiT blocks with adaLN-Zero conditioning, self-attention over tokens and cross-attention to a context.

Both stages use them: the local denoiser's object (+ frame) tokens attend to scene tokens; the Dense GMM's
scene tokens attend to object tokens. LayerNorms carry no affine parameters (eps 1e-6); modulation and
output layers start at zero so every block starts as the identity.

What every block derives from the inputs they share (the normalised context's keys and values, the
modulation from the condition) the `DiT` computes for all blocks at once, one matrix product each with the
blocks' weights side by side: the same values for a handful of kernel launches instead of a handful a block.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn


def _norm(dim: int) -> nn.LayerNorm:
    return nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)


def _modulate(x: Tensor, shift: Tensor, scale: Tensor) -> Tensor:
    return x * (1.0 + scale.unsqueeze(1)) + shift.unsqueeze(1)


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

    Its modulation (`modulation(condition)`) and the context's keys and values (`cross_attention.key_value(LN
    ctx)`) come from the `DiT`, which computes them for all its blocks together."""

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

    def forward(self, x: Tensor, context_keys_values: Tensor, modulation: Tensor) -> Tensor:
        (s1, c1, g1, s2, c2, g2, s3, c3, g3) = modulation.chunk(9, dim=-1)
        h = _modulate(self.norm_self(x), s1, c1)
        x = x + g1.unsqueeze(1) * self.self_attention(h, h)
        h = _modulate(self.norm_cross(x), s2, c2)
        x = x + g2.unsqueeze(1) * self.cross_attention.attend(h, context_keys_values)
        return x + g3.unsqueeze(1) * self.mlp(_modulate(self.norm_mlp(x), s3, c3))


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

    def forward(self, x: Tensor, condition: Tensor) -> Tensor:
        shift, scale = self.modulation(condition).chunk(2, dim=-1)
        return self.linear(_modulate(self.norm(x), shift, scale))


class DiT(nn.Module):
    """A stack of `DiTBlock`s over tokens (B, T, dim) attending to a context (B, C, dim)."""

    def __init__(self, dim: int, num_heads: int, num_blocks: int, mlp_ratio: float) -> None:
        super().__init__()
        self.blocks = nn.ModuleList(DiTBlock(dim, num_heads, mlp_ratio) for _ in range(num_blocks))
        self.norm_context = _norm(dim)

    def forward(self, tokens: Tensor, context: Tensor, condition: Tensor) -> Tensor:
        blocks = len(self.blocks)
        modulations = linear_together([b.modulation[-1] for b in self.blocks], F.silu(condition)).chunk(blocks, -1)
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
