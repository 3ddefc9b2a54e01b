"""The diffusion scheduler inverts its own forward process."""

import torch

from lerobot_taxdpd.policies.taxdpd.schedulers import DiffusionScheduler


def test_schedule_ends_in_noise():
    scheduler = DiffusionScheduler(100)
    assert scheduler.alphas_cumprod[-1] < 1e-4  # rescaled betas: the last step is (almost) pure noise
    assert scheduler.alphas_cumprod[0] > 0.98


def test_ddim_with_the_true_noise_recovers_the_sample_in_any_number_of_steps():
    g = torch.Generator().manual_seed(0)
    scheduler = DiffusionScheduler(100)
    clean = torch.randn(4, 32, 3, generator=g, dtype=torch.float64)
    noise = torch.randn(clean.shape, generator=g, dtype=torch.float64)
    for steps in (1, 5, 100):
        timesteps = scheduler.inference_timesteps(steps)
        sample = scheduler.add_noise(clean, noise, torch.full((4,), timesteps[0][0]))
        for t, t_prev in timesteps:
            a = scheduler.alphas_cumprod[t]
            oracle = (sample - a.sqrt() * clean) / (1 - a).sqrt()
            sample = scheduler.step(oracle, t, t_prev, sample)
        assert torch.allclose(sample, clean, atol=1e-9)


def test_ddpm_step_needs_noise_and_adds_it():
    scheduler = DiffusionScheduler(100)
    sample = torch.zeros(2, 8, 3)
    deterministic = scheduler.step(torch.zeros_like(sample), 50, 49, sample)
    stochastic = scheduler.step(torch.zeros_like(sample), 50, 49, sample, eta=1.0, noise=torch.ones_like(sample))
    assert not torch.allclose(deterministic, stochastic)
