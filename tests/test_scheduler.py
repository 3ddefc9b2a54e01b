"""The local stage's noise process (diffusers' DDPM and DDIM schedulers) inverts itself exactly."""

import pytest
import torch

from lerobot_taxdpd import TaxDPDConfig
from lerobot_taxdpd.policies.taxdpd.schedulers import (
    DDIMSampler,
    make_sampling_scheduler,
    make_training_scheduler,
    training_target,
)
from lerobot_taxdpd.reports.launches import LaunchCounter


def _config(prediction_type: str = "sample") -> TaxDPDConfig:
    return TaxDPDConfig.for_point_clouds(32, 64, device="cpu", prediction_type=prediction_type, rotation_noise="paper")


def test_schedule_ends_in_noise_and_sampling_starts_there():
    training = make_training_scheduler(_config())
    assert training.alphas_cumprod[-1] < 1e-4  # rescaled betas: the last step is (almost) pure noise
    assert training.alphas_cumprod[0] > 0.98
    sampling = make_sampling_scheduler(_config())
    sampling.set_timesteps(10)
    assert sampling.timesteps[0] == 99 and sampling.timesteps[-1] == 9


@pytest.mark.parametrize("prediction_type", ["epsilon", "sample", "v_prediction"])
def test_ddim_with_the_true_target_recovers_the_sample_in_any_valid_number_of_steps(prediction_type):
    g = torch.Generator().manual_seed(0)
    config = _config(prediction_type)
    training, sampling = make_training_scheduler(config), make_sampling_scheduler(config)
    clean = torch.randn(4, 32, 3, generator=g, dtype=torch.float64)
    noise = torch.randn(clean.shape, generator=g, dtype=torch.float64)
    for steps in (1, 5, 100):
        sampling.set_timesteps(steps)
        sample = training.add_noise(clean, noise, sampling.timesteps[:1].expand(4))
        for t in sampling.timesteps:
            # the exact target at (sample, t): the sample's own noise, given the clean sample
            a = training.alphas_cumprod[t].double()
            oracle_noise = (sample - a.sqrt() * clean) / (1 - a).sqrt()
            target = training_target(training, clean, oracle_noise, t.expand(4))
            sample = sampling.step(target, t, sample).prev_sample
        assert torch.allclose(sample, clean, atol=1e-5)  # diffusers keeps alpha_bar in float32


@pytest.mark.parametrize("steps", [0, 3, 7, 101])
def test_step_counts_that_would_pair_timesteps_inexactly_are_refused(steps):
    with pytest.raises(ValueError, match="num_inference_steps: must divide"):
        TaxDPDConfig.for_point_clouds(32, 64, device="cpu", num_inference_steps=steps)


@pytest.mark.parametrize("prediction_type", ["epsilon", "sample", "v_prediction"])
@pytest.mark.parametrize("eta", [0.0, 1.0])
def test_the_float_coefficient_sampler_takes_diffusers_ddim_steps(prediction_type, eta):
    g = torch.Generator().manual_seed(1)
    config = _config(prediction_type)
    reference, sampler = make_sampling_scheduler(config), DDIMSampler(config)
    for steps in (1, 10, 100):
        reference.set_timesteps(steps)
        ours = sampler.steps(steps)
        assert [s.timestep for s in ours] == reference.timesteps.tolist()
        sample = torch.randn(4, 32, 3, generator=g)
        for step, t in zip(ours, reference.timesteps, strict=True):
            output, noise = torch.randn(sample.shape, generator=g), torch.randn(sample.shape, generator=g)
            expected = reference.step(output, t, sample, eta=eta, variance_noise=noise).prev_sample
            taken = sampler.step(output, step, sample, eta, noise)
            torch.testing.assert_close(taken, expected, rtol=1e-5, atol=1e-5)
            sample = expected


@pytest.mark.parametrize("prediction_type", ["epsilon", "sample", "v_prediction"])
def test_a_deterministic_ddim_step_is_one_linear_combination(prediction_type):
    """Two launches a step (a product and a scaled sum) whatever the target: on a GPU each op of the update
    is a kernel launch between the denoiser's passes."""
    sampler = DDIMSampler(_config(prediction_type))
    g = torch.Generator().manual_seed(2)
    sample, output = torch.randn(4, 32, 3, generator=g), torch.randn(4, 32, 3, generator=g)
    for step in sampler.steps(10):
        counter = LaunchCounter()
        with counter:
            sampler.step(output, step, sample)
        assert counter.total_ops() == 2, counter.ops
