"""Mixed precision: the linear layers' bf16 weights cast together for an autocast step, and whether bf16 pays
on this CPU at all.

Under autocast every linear layer casts its fp32 weight and bias to bf16 in the forward pass, and its gradients
back to fp32 in the backward pass: four kernel launches a layer, about 600 of a paper-size training step's
3,200. Casting all of them at once (one concatenation, one cast) and running the network on the casts gives
the same bf16 values and the same fp32 gradients, so the same step, for four launches in all. The fp32 weights
stay the parameters the optimiser, the clipping and the weight average see.

On a CPU, AMP pays only where the CPU has bf16 instructions; without them torch falls back to kernels far
slower than fp32 ones (an AMD EPYC without avx512_bf16: 0.65 against 26 GFLOP/s, so the learning test's step
took 1.73 s with AMP against 0.24 s without). `warn_if_amp_is_slow` measures it once and says so.
"""

from __future__ import annotations

import functools
import time
import warnings

import torch
from torch import Tensor, nn
from torch.func import functional_call


class _CastTogether(torch.autograd.Function):
    """Tensors -> their casts to `dtype`, views of one buffer; gradients cast back the same way."""

    @staticmethod
    def forward(ctx, dtype: torch.dtype, *tensors: Tensor) -> tuple[Tensor, ...]:
        ctx.source_dtype = tensors[0].dtype
        ctx.shapes = [t.shape for t in tensors]
        flat = torch.cat([t.reshape(-1) for t in tensors]).to(dtype)
        parts = flat.split([t.numel() for t in tensors])
        return tuple(part.view(shape) for part, shape in zip(parts, ctx.shapes, strict=True))

    @staticmethod
    def backward(ctx, *grads: Tensor | None) -> tuple[None | Tensor, ...]:
        # A weight no loss reached keeps no gradient (as without the cast), so the optimiser skips it.
        present = [i for i, g in enumerate(grads) if g is not None]
        out: list[Tensor | None] = [None] * len(grads)
        if present:
            flat = torch.cat([grads[i].reshape(-1) for i in present]).to(ctx.source_dtype)
            parts = flat.split([ctx.shapes[i].numel() for i in present])
            for i, part in zip(present, parts, strict=True):
                out[i] = part.view(ctx.shapes[i])
        return (None, *out)


def linear_parameters(module: nn.Module) -> dict[str, Tensor]:
    """Every weight and bias of the linear layers below `module`, by name (those autocast computes in bf16)."""
    return {
        f"{name}.{field}" if name else field: tensor
        for name, sub in module.named_modules()
        if isinstance(sub, nn.Linear)
        for field, tensor in sub.named_parameters(recurse=False)
    }


def call_with_linears_cast(module: nn.Module, dtype: torch.dtype, *args, **kwargs):
    """`module(*args, **kwargs)` with its linear layers on casts of their weights to `dtype` made in one op,
    whose gradients flow back to the fp32 weights in one op. For autocast training steps."""
    named = linear_parameters(module)
    casts = _CastTogether.apply(dtype, *named.values())
    return functional_call(module, dict(zip(named, casts, strict=True)), args, kwargs)


@functools.lru_cache(maxsize=1)
def cpu_bf16_speedup(size: int = 256, repeats: int = 3) -> float:
    """How many times faster a bf16 matrix product runs than an fp32 one on this CPU (best times of `repeats`;
    measured once per process, about 0.1-0.3 s)."""

    def best_seconds(dtype: torch.dtype) -> float:
        a, b = torch.randn(size, size).to(dtype), torch.randn(size, size).to(dtype)
        a @ b
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            a @ b
            times.append(time.perf_counter() - start)
        return min(times)

    return best_seconds(torch.float32) / best_seconds(torch.bfloat16)


def warn_if_amp_is_slow(config) -> None:
    """A policy built with `use_amp` to run on a CPU whose bf16 products are slower than its fp32 ones would
    train and sample slower, not faster: warn, with the measured ratio and the flag that turns it off."""
    device = config.device or ("cuda" if torch.cuda.is_available() else "cpu")
    if not config.use_amp or torch.device(device).type != "cpu":
        return
    speedup = cpu_bf16_speedup()
    if speedup < 1.0:
        warnings.warn(
            f"use_amp=true on a CPU whose bf16 matrix products run {1 / speedup:.1f}x slower than fp32 ones (no "
            "bf16 instructions): training and sampling will be slower, not faster; set --policy.use_amp=false",
            UserWarning,
            stacklevel=3,
        )
