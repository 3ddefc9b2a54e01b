"""`position_octaves`: Fourier features of the local stage's token positions. A model with them starts as the
model without them, trains them, and keeps them through a checkpoint."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch
from safetensors.torch import load_file, save_file

from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.policies.checkpoints import CheckpointError
from lerobot_taxdpd.policies.taxdpd.model.positions import BASE_FREQUENCY, FourierPositions


def _policy(**overrides) -> TaxDPDPolicy:
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(
        32, 64, hidden_dim=16, num_blocks=1, num_heads=2, point_scale=20.0, device="cpu", **overrides
    )
    return TaxDPDPolicy(config)


def _clouds() -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    return torch.rand(2, 32, 3, generator=g) * 0.1, torch.rand(2, 64, 3, generator=g)


def _randomised(policy: TaxDPDPolicy) -> TaxDPDPolicy:
    """Random weights everywhere but the position projection: the zero-initialised output heads would otherwise
    predict nothing, and the comparison would hold trivially."""
    with torch.no_grad():
        for name, parameter in policy.named_parameters():
            if ".positions." not in name:
                parameter.normal_(0.0, 0.2)
    return policy


def test_the_features_are_sines_and_cosines_of_each_coordinate_at_octave_frequencies():
    encoding = FourierPositions(dim=4, octaves=3)
    torch.testing.assert_close(encoding.frequencies, BASE_FREQUENCY * torch.tensor([1.0, 2.0, 4.0]))
    with torch.no_grad():
        encoding.projection.weight.zero_()
        encoding.projection.weight[0, 2] = 1.0  # sin of x at the third octave
        encoding.projection.weight[1, 9 + 3] = 1.0  # cos of y at the first
    xyz = torch.tensor([[0.3, -1.2, 2.0]])
    out = encoding(xyz)
    torch.testing.assert_close(out[0, 0], torch.tensor(math.sin(4 * BASE_FREQUENCY * 0.3)))
    torch.testing.assert_close(out[0, 1], torch.tensor(math.cos(BASE_FREQUENCY * -1.2)))
    assert out[0, 2:].abs().max() == 0


def test_a_model_with_positions_starts_as_the_model_without_them():
    """The projection starts at zero, so the paper's model's weights give the same samples with the switch on."""
    plain = _randomised(_policy()).eval()
    with_positions = _policy(position_octaves=6).eval()
    missing, unexpected = with_positions.load_state_dict(plain.state_dict(), strict=False)
    assert set(missing) == {
        "model.local_stage.denoiser.positions.projection.weight",
        "model.local_stage.denoiser.positions.projection.bias",
    }
    assert not unexpected
    obj, scene = _clouds()
    goals = [p.sample_goals(obj, scene, 3, generator=torch.Generator().manual_seed(1)) for p in (plain, with_positions)]
    torch.testing.assert_close(goals[0], goals[1])


def test_the_positions_are_trained_and_change_the_goals(tmp_path):
    policy = _randomised(_policy(position_octaves=6)).train()
    obj, scene = _clouds()
    loss, _ = policy.forward({OBJECT_KEY: obj, SCENE_KEY: scene, ACTION_KEY: obj + 0.2})
    loss.backward()
    projection = policy.model.local_stage.denoiser.positions.projection
    assert projection.weight.grad.abs().max() > 0

    policy.eval()
    before = policy.sample_goals(obj, scene, 3, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        projection.weight.normal_(0.0, 0.5)
    after = policy.sample_goals(obj, scene, 3, generator=torch.Generator().manual_seed(1))
    assert (after - before).abs().max() > 1e-3

    policy.save_pretrained(tmp_path)
    loaded = TaxDPDPolicy.from_pretrained(tmp_path).eval()
    assert loaded.config.position_octaves == 6
    torch.testing.assert_close(loaded.sample_goals(obj, scene, 3, generator=torch.Generator().manual_seed(1)), after)


@pytest.mark.parametrize("octaves", [-1, 13, 2.5, True])
def test_octaves_it_cannot_serve_are_refused_by_name(octaves):
    with pytest.raises(ValueError, match="position_octaves: an integer in"):
        TaxDPDConfig.for_point_clouds(32, 64, position_octaves=octaves)


def test_a_predictor_saved_without_positions_fine_tunes_with_them(tmp_path):
    """`lerobot-train --policy.path=SHIPPED --policy.position_octaves=N` (what `sim pretrain --init-from` runs): the
    file's model has no projection, the new one starts at zero and so samples as the file's model did. A file
    saved with the switch on but without its projection is refused as damaged."""
    plain = _randomised(_policy()).eval()
    plain.save_pretrained(tmp_path / "plain")
    switched_on = dataclasses.replace(plain.config, position_octaves=6)
    tuned = TaxDPDPolicy.from_pretrained(tmp_path / "plain", config=switched_on).eval()
    assert tuned.config.position_octaves == 6
    obj, scene = _clouds()
    goals = [p.sample_goals(obj, scene, 3, generator=torch.Generator().manual_seed(1)) for p in (plain, tuned)]
    torch.testing.assert_close(goals[0], goals[1])

    _policy(position_octaves=6).save_pretrained(tmp_path / "damaged")
    weights = tmp_path / "damaged" / "model.safetensors"
    save_file({n: t for n, t in load_file(weights).items() if ".positions." not in n}, weights)
    with pytest.raises(CheckpointError, match=r"model\.safetensors: does not fit.*positions\.projection"):
        TaxDPDPolicy.from_pretrained(tmp_path / "damaged")
