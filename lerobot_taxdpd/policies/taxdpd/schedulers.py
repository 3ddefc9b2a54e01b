"""A small Gaussian diffusion scheduler (DDPM training, DDIM/DDPM sampling) for epsilon, sample or v targets."""

from __future__ import annotations

import torch
from torch import Tensor


class DiffusionScheduler:
    """Linear beta schedule over `num_train_timesteps`, with one reverse step for DDIM and DDPM.

    `beta_start`/`beta_end` are given for a 1000-step process and rescaled by 1000/T, as in improved DDPM
    and DiT: with T = 100 the plain range (1e-4, 0.02) would leave sqrt(alpha_bar_T) ~ 0.6 of the signal,
    so samples would start from a distribution the model never saw.

    The reverse step is the DDIM update with stochasticity `eta`: eta = 0 is deterministic DDIM (few steps),
    eta = 1 on the full schedule is ancestral DDPM sampling with the posterior variance.
    """

    def __init__(self, num_train_timesteps: int = 100, beta_start: float = 1e-4, beta_end: float = 0.02) -> None:
        self.num_train_timesteps = num_train_timesteps
        scale = 1000.0 / num_train_timesteps
        betas = torch.linspace(scale * beta_start, scale * beta_end, num_train_timesteps, dtype=torch.float64)
        self.alphas_cumprod = torch.cumprod(1.0 - betas, dim=0)

    def _alpha_bar(self, t: Tensor, like: Tensor) -> Tensor:
        """alpha_bar at integer timesteps t (B,), shaped to broadcast against `like` (B, ...); t < 0 -> 1."""
        values = torch.where(
            t >= 0, self.alphas_cumprod.to(t.device)[t.clamp_min(0)], torch.ones((), dtype=torch.float64, device=t.device)
        )
        return values.to(like.dtype).reshape(-1, *([1] * (like.dim() - 1)))

    def add_noise(self, sample: Tensor, noise: Tensor, t: Tensor) -> Tensor:
        a = self._alpha_bar(t, sample)
        return a.sqrt() * sample + (1.0 - a).sqrt() * noise

    def target(self, prediction_type: str, sample: Tensor, noise: Tensor, t: Tensor) -> Tensor:
        """What the network is trained to output: the noise, the clean sample, or v = sqrt(a) eps - sqrt(1-a) x0."""
        if prediction_type == "epsilon":
            return noise
        if prediction_type == "sample":
            return sample
        a = self._alpha_bar(t, sample)
        return a.sqrt() * noise - (1.0 - a).sqrt() * sample

    def to_noise(self, prediction_type: str, output: Tensor, noisy: Tensor, t: int) -> Tensor:
        """The noise estimate implied by a network output of `prediction_type` at step t."""
        if prediction_type == "epsilon":
            return output
        a = self._alpha_bar(torch.full((noisy.shape[0],), t, device=noisy.device), noisy)
        if prediction_type == "sample":
            return (noisy - a.sqrt() * output) / (1.0 - a).sqrt()
        return a.sqrt() * output + (1.0 - a).sqrt() * noisy

    def inference_timesteps(self, num_inference_steps: int) -> list[tuple[int, int]]:
        """(t, t_prev) pairs from T-1 down to 0, evenly spaced; t_prev = -1 marks the final clean sample."""
        steps = torch.linspace(self.num_train_timesteps - 1, 0, num_inference_steps).round().long().tolist()
        return list(zip(steps, steps[1:] + [-1], strict=True))

    def step(
        self,
        predicted_noise: Tensor,
        t: int,
        t_prev: int,
        sample: Tensor,
        *,
        eta: float = 0.0,
        noise: Tensor | None = None,
    ) -> Tensor:
        """One reverse step x_t -> x_{t_prev}. `noise` (same shape as sample) is needed when eta > 0."""
        batch = sample.shape[0]
        a_t = self._alpha_bar(torch.full((batch,), t, device=sample.device), sample)
        a_prev = self._alpha_bar(torch.full((batch,), t_prev, device=sample.device), sample)
        clean = (sample - (1.0 - a_t).sqrt() * predicted_noise) / a_t.sqrt()
        sigma = eta * ((1.0 - a_prev) / (1.0 - a_t) * (1.0 - a_t / a_prev)).clamp_min(0.0).sqrt()
        direction = (1.0 - a_prev - sigma**2).clamp_min(0.0).sqrt() * predicted_noise
        previous = a_prev.sqrt() * clean + direction
        if eta > 0 and t_prev >= 0:
            if noise is None:
                raise ValueError("noise: required when eta > 0")
            previous = previous + sigma * noise
        return previous
