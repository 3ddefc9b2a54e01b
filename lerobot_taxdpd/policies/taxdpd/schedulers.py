"""The local stage's noise process, in diffusers' vocabulary: DDPM for training, DDIM for sampling.

`beta_start`/`beta_end` are given for a 1000-step process and rescaled by 1000/T, as in improved DDPM and
DiT: with T = 100 the plain range (1e-4, 0.02) would leave sqrt(alpha_bar_T) ~ 0.6 of the signal, so samples
would start from a distribution the model never saw. Sampling uses "trailing" timesteps, so the first step
starts at T - 1 (pure noise) and the last one lands on the clean sample.

`DDIMSampler` takes diffusers' DDIM update with every coefficient a Python float: diffusers' `step` does its
scalar arithmetic on 0-d tensors and compares them in Python, a dozen host ops and reads per call, which
on a GPU sit between the launches of every denoising step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from diffusers import DDIMScheduler, DDPMScheduler
from torch import Tensor


def noise_schedule_kwargs(config) -> dict:
    """The schedule both schedulers share, from a TaxDPDConfig."""
    scale = 1000.0 / config.num_train_timesteps
    return dict(
        num_train_timesteps=config.num_train_timesteps,
        beta_start=scale * config.beta_start,
        beta_end=scale * config.beta_end,
        beta_schedule="linear",
        prediction_type=config.prediction_type,
        clip_sample=False,
    )


def make_training_scheduler(config) -> DDPMScheduler:
    return DDPMScheduler(**noise_schedule_kwargs(config))


def make_sampling_scheduler(config) -> DDIMScheduler:
    return DDIMScheduler(**noise_schedule_kwargs(config), timestep_spacing="trailing", set_alpha_to_one=True)


@dataclass(frozen=True)
class DDIMStep:
    """From timestep `timestep` (signal level `alpha_bar`) to the previous one (`alpha_bar_prev`)."""

    timestep: int
    alpha_bar: float
    alpha_bar_prev: float


class DDIMSampler:
    """The DDIM update of `make_sampling_scheduler`'s scheduler ("trailing" timesteps, alpha_bar = 1 after the
    last step, no clipping), computed with Python-float coefficients: elementwise ops on the sample only."""

    def __init__(self, config) -> None:
        reference = make_sampling_scheduler(config)
        self.alphas_cumprod = reference.alphas_cumprod.double().tolist()
        self.num_train_timesteps = config.num_train_timesteps
        self.prediction_type = config.prediction_type

    def steps(self, num_inference_steps: int) -> list[DDIMStep]:
        """The denoising steps, first (pure noise, T - 1) to last; `num_inference_steps` divides T."""
        stride = self.num_train_timesteps // num_inference_steps
        timesteps = range(self.num_train_timesteps - 1, -1, -stride)
        return [
            DDIMStep(t, self.alphas_cumprod[t], self.alphas_cumprod[t - stride] if t >= stride else 1.0)
            for t in timesteps
        ]

    def step(
        self, model_output: Tensor, step: DDIMStep, sample: Tensor, eta: float = 0.0, noise: Tensor | None = None
    ) -> Tensor:
        """The sample at the previous timestep; `noise` (standard normal) is needed when `eta` > 0.

        The clean estimate and the noise are both linear in (sample, model output), so the update is one
        linear combination of the two (two launches) with its coefficients worked out in Python."""
        a, a_prev = step.alpha_bar, step.alpha_bar_prev
        # (clean, epsilon) = (c_s * sample + c_o * model_output, e_s * sample + e_o * model_output)
        if self.prediction_type == "epsilon":
            c_s, c_o, e_s, e_o = 1 / math.sqrt(a), -math.sqrt(1 - a) / math.sqrt(a), 0.0, 1.0
        elif self.prediction_type == "sample":
            c_s, c_o, e_s, e_o = 0.0, 1.0, 1 / math.sqrt(1 - a), -math.sqrt(a) / math.sqrt(1 - a)
        else:  # v_prediction
            c_s, c_o, e_s, e_o = math.sqrt(a), -math.sqrt(1 - a), math.sqrt(1 - a), math.sqrt(a)
        std = eta * math.sqrt((1 - a_prev) / (1 - a) * (1 - a / a_prev))
        keep, towards = math.sqrt(a_prev), math.sqrt(max(1 - a_prev - std**2, 0.0))
        previous = (sample * (keep * c_s + towards * e_s)).add_(model_output, alpha=keep * c_o + towards * e_o)
        return previous + std * noise if std > 0 else previous


def training_target(scheduler: DDPMScheduler, clean: Tensor, noise: Tensor, t: Tensor) -> Tensor:
    """What the denoiser learns to output at step t: the noise, the clean sample, or v."""
    prediction_type = scheduler.config.prediction_type
    if prediction_type == "epsilon":
        return noise
    if prediction_type == "sample":
        return clean
    return scheduler.get_velocity(clean, noise, t)
