"""The local stage's noise process, in diffusers' vocabulary: DDPM for training, DDIM for sampling.

`beta_start`/`beta_end` are given for a 1000-step process and rescaled by 1000/T, as in improved DDPM and
DiT: with T = 100 the plain range (1e-4, 0.02) would leave sqrt(alpha_bar_T) ~ 0.6 of the signal, so samples
would start from a distribution the model never saw. Sampling uses "trailing" timesteps, so the first step
starts at T - 1 (pure noise) and the last one lands on the clean sample.
"""

from __future__ import annotations

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


def training_target(scheduler: DDPMScheduler, clean: Tensor, noise: Tensor, t: Tensor) -> Tensor:
    """What the denoiser learns to output at step t: the noise, the clean sample, or v."""
    prediction_type = scheduler.config.prediction_type
    if prediction_type == "epsilon":
        return noise
    if prediction_type == "sample":
        return clean
    return scheduler.get_velocity(clean, noise, t)
