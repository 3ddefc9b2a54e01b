"""The local stage's loss weights: `rotation_loss_weight`, a pose-level term that weighs the rigid turn of the
predicted goal, which the point loss weighs far below the points' scatter, `spread_loss_weight`, a shape-level
term that charges a goal squashed across an axis, and `frame_loss_weight`, the goal centroid's share against
the shape's."""

from __future__ import annotations

import math

import pytest
import torch

from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.maths.geometry import axis_angle_to_matrix, principal_spreads, small_rotation_between


def _centred(x: torch.Tensor) -> torch.Tensor:
    return x - x.mean(dim=-2, keepdim=True)


def _box_cloud(batch: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return _centred(torch.rand(batch, 128, 3, generator=g) * torch.tensor([3.0, 1.0, 0.5]))


def _ring_cloud(batch: int) -> torch.Tensor:
    """A round plug: two circles, whose covariance has a repeated singular value."""
    angle = torch.linspace(0, 2 * math.pi, 65)[:-1]
    circle = torch.stack([angle.cos(), angle.sin(), torch.zeros_like(angle)], -1)
    return _centred(torch.cat([circle, circle + torch.tensor([0.0, 0.0, 1.0])]).expand(batch, -1, -1).clone())


@pytest.mark.parametrize("make_cloud", [_box_cloud, _ring_cloud], ids=["box", "round"])
def test_the_turn_between_two_clouds_is_recovered_in_angle_and_axis(make_cloud):
    reference = make_cloud(4)
    axis = torch.nn.functional.normalize(torch.randn(4, 3, generator=torch.Generator().manual_seed(1)), dim=-1)
    angle = torch.tensor([0.005, 0.02, 0.05, 0.2])
    moved = reference @ axis_angle_to_matrix(axis, angle).transpose(-1, -2)
    turn = small_rotation_between(reference, moved)
    torch.testing.assert_close(turn.norm(dim=-1), angle, rtol=0.02, atol=1e-6)
    assert (torch.nn.functional.normalize(turn, dim=-1) * axis).sum(-1).min() > 0.999


def test_stretching_and_scatter_are_not_a_turn_but_a_turn_of_the_same_point_error_is():
    """Two predictions 0.05 units (rms) from the goal: scattered points show no turn, a turned copy its 1.4 deg."""
    goal = _box_cloud(8)
    assert small_rotation_between(goal, 1.1 * goal).abs().max() < 1e-6
    rms = 0.05
    scatter = torch.randn(goal.shape, generator=torch.Generator().manual_seed(2))
    scattered = goal + rms * _centred(scatter) / _centred(scatter).pow(2).mean().sqrt()
    radius = goal.pow(2).sum(-1).mean().sqrt()
    angle = rms * math.sqrt(3) / radius.item() * math.sqrt(1.5)  # the rms of a turn about an average axis
    turned = goal @ axis_angle_to_matrix(torch.tensor([0.0, 0.0, 1.0]), torch.tensor(angle)).T
    scattered_turn = small_rotation_between(goal, scattered).norm(dim=-1)
    turned_turn = small_rotation_between(goal, turned).norm(dim=-1)
    assert scattered_turn.median() < 0.2 * turned_turn.median()
    torch.testing.assert_close(turned_turn, torch.full_like(turned_turn, angle), rtol=0.02, atol=0.0)


def test_the_gradient_is_finite_for_round_shapes():
    reference = _ring_cloud(2)
    noise = torch.randn(reference.shape, generator=torch.Generator().manual_seed(3))
    moved = (reference + 0.01 * noise).requires_grad_()
    small_rotation_between(reference, moved).pow(2).sum().backward()
    assert moved.grad.isfinite().all() and moved.grad.abs().max() > 0


def test_the_spreads_are_a_boxs_extents_in_any_orientation_and_a_flattened_one_shows():
    """A 3 x 1 x 0.5 box's principal spreads are its extents / sqrt(12) whichever way it is turned; squashing
    its thin axis tenfold shows there and nowhere else, and a flat cloud keeps a finite gradient."""
    box = _box_cloud(4)
    axis = torch.nn.functional.normalize(torch.tensor([0.3, -0.5, 0.8]), dim=0)
    turned = box @ axis_angle_to_matrix(axis, torch.tensor(1.1)).T
    expected = torch.tensor([0.5, 1.0, 3.0]) / math.sqrt(12)
    torch.testing.assert_close(principal_spreads(box), expected.expand(4, 3), rtol=0.1, atol=0.0)
    torch.testing.assert_close(principal_spreads(turned), principal_spreads(box), rtol=1e-4, atol=1e-6)
    squashed = principal_spreads(box * torch.tensor([1.0, 1.0, 0.1])) / principal_spreads(box)
    torch.testing.assert_close(squashed, torch.tensor([0.1, 1.0, 1.0]).expand(4, 3), rtol=0.0, atol=0.01)
    flat = (box * torch.tensor([1.0, 1.0, 0.0])).requires_grad_()
    principal_spreads(flat).sum().backward()
    assert flat.grad.isfinite().all()


def _policy(**overrides) -> TaxDPDPolicy:
    torch.manual_seed(0)
    config = TaxDPDConfig.for_point_clouds(
        32, 64, hidden_dim=16, num_blocks=1, num_heads=2, point_scale=20.0, device="cpu", **overrides
    )
    policy = TaxDPDPolicy(config).train()
    with torch.no_grad():  # random weights: the zero-initialised output heads would predict no shape at all
        for parameter in policy.parameters():
            parameter.normal_(0.0, 0.2)
    return policy


def _losses_beside_the_default(**overrides) -> tuple[torch.Tensor, dict, dict, TaxDPDPolicy]:
    """One training batch through the default policy and through one with `overrides`: same weights, same noise."""
    g = torch.Generator().manual_seed(0)
    obj, scene = torch.rand(4, 32, 3, generator=g) * 0.1, torch.rand(4, 64, 3, generator=g)
    batch = {OBJECT_KEY: obj, SCENE_KEY: scene, ACTION_KEY: obj + 0.2}
    plain_policy, weighted = _policy(), _policy(**overrides)
    torch.manual_seed(5)
    _, plain = plain_policy.forward(batch)
    torch.manual_seed(5)
    loss, parts = weighted.forward(batch)
    return loss, parts, plain, weighted


def test_the_term_adds_to_the_local_loss_and_reaches_every_parameter():
    loss, parts, plain, weighted = _losses_beside_the_default(rotation_loss_weight=10.0)
    loss.backward()
    assert all(p.grad is not None for p in weighted.parameters())
    term = parts["loss_pose_rotation"]
    assert term > 0
    torch.testing.assert_close(parts["loss_shape"], plain["loss_shape"])
    torch.testing.assert_close(parts["loss_local"], plain["loss_local"] + 10.0 * term)


def test_the_spread_term_adds_to_the_local_loss_beside_the_pose_term():
    loss, parts, plain, weighted = _losses_beside_the_default(rotation_loss_weight=10.0, spread_loss_weight=3.0)
    loss.backward()
    assert all(p.grad is not None for p in weighted.parameters())
    spread, turn = parts["loss_shape_spread"], parts["loss_pose_rotation"]
    assert spread > 0
    torch.testing.assert_close(parts["loss_local"], plain["loss_local"] + 10.0 * turn + 3.0 * spread)


def test_the_frame_weight_scales_the_frame_term_alone():
    _, parts, plain, _ = _losses_beside_the_default(frame_loss_weight=5.0)
    torch.testing.assert_close(parts["loss_frame"], plain["loss_frame"])
    torch.testing.assert_close(parts["loss_local"], plain["loss_local"] + 0.5 * 4.0 * plain["loss_frame"])


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (dict(rotation_loss_weight=-1.0), "rotation_loss_weight: must be >= 0"),
        (
            dict(rotation_loss_weight=1.0, prediction_type="epsilon", use_rotation_noise=False),
            "prediction_type='sample'",
        ),
        (dict(rotation_loss_weight=1.0, local_diffusion="se3"), "local_diffusion='point'"),
        (dict(spread_loss_weight=-0.5), "spread_loss_weight: must be >= 0"),
        (dict(spread_loss_weight=1.0, local_diffusion="se3"), "spread_loss_weight: needs"),
        (dict(frame_loss_weight=0.0), "frame_loss_weight: must be positive"),
        (dict(frame_loss_weight=2.0, disentangled=False), "frame_loss_weight: needs disentangled=true"),
    ],
    ids=["negative", "noise-target", "se3", "spread-negative", "spread-se3", "frame-zero", "frame-joint"],
)
def test_settings_it_cannot_serve_are_refused_by_name(overrides, message):
    with pytest.raises(ValueError, match=message):
        TaxDPDConfig.for_point_clouds(32, 64, **overrides)
