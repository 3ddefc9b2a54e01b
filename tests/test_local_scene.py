"""`local_scene_points`: the local stage sees the scene points nearest its placement frame, at the density the
scene was given, and nothing farther away."""

from __future__ import annotations

import pytest
import torch

from lerobot_taxdpd import TaxDPDConfig, TaxDPDPolicy
from lerobot_taxdpd.data.schema import ACTION_KEY, OBJECT_KEY, SCENE_KEY
from lerobot_taxdpd.maths.geometry import nearest_points


def _policy(local_scene_points: int, with_whole: bool = False) -> TaxDPDPolicy:
    torch.manual_seed(0)
    fields = dict(hidden_dim=16, num_blocks=1, num_heads=2, max_neighbors=8, point_scale=20.0)
    config = TaxDPDConfig.for_point_clouds(
        32, 64, device="cpu", local_scene_points=local_scene_points, local_scene_with_whole=with_whole, **fields
    )
    return TaxDPDPolicy(config)


def test_nearest_points_are_the_nearest_nearest_first():
    g = torch.Generator().manual_seed(0)
    points, centres = torch.rand(3, 100, 3, generator=g), torch.rand(3, 3, generator=g)
    picked = nearest_points(points, centres, 10)
    distances = (points - centres[:, None]).norm(dim=-1)
    expected = distances.sort(dim=1).values[:, :10]
    torch.testing.assert_close((picked - centres[:, None]).norm(dim=-1), expected)


@pytest.mark.parametrize(
    ("local_scene_points", "with_whole"),
    [(0, False), (48, False), (48, True)],
    ids=["whole-scene", "local-scene", "local-scene-beside-whole"],
)
def test_clutter_far_from_the_placement_frame_changes_the_goals_only_without_the_whole_scene(
    local_scene_points, with_whole
):
    """At given placement frames, a crop of the 48 points nearest each frame ignores clutter 5 m away; the paper's
    layout, which shows the local stage the whole (reduced) scene, does not, nor does the crop beside it."""
    policy = _policy(local_scene_points, with_whole).eval()
    with torch.no_grad():  # random weights: the DiT's zero-initialised blocks would ignore every scene at first
        for parameter in policy.parameters():
            parameter.normal_(0.0, 0.2)
    g = torch.Generator().manual_seed(1)
    objects, scene = torch.rand(2, 32, 3, generator=g) * 0.1, torch.rand(2, 200, 3, generator=g)
    cluttered = torch.cat([scene, torch.rand(2, 100, 3, generator=g) + 5.0], 1)
    frames = torch.tensor([[0.5, 0.5, 0.5], [0.2, 0.3, 0.4]])

    def goals(scene_points):
        generator = torch.Generator().manual_seed(0)
        return policy.sample_goals(objects, scene_points, 3, generator=generator, placement_frames=frames)

    change = (goals(scene) - goals(cluttered)).abs().max().item()
    if local_scene_points and not with_whole:
        assert change < 1e-5
    else:
        assert change > 1e-3


@pytest.mark.parametrize("with_whole", [False, True], ids=["crop", "crop-beside-whole"])
def test_a_local_scene_policy_trains_and_samples_from_scenes_denser_than_its_network_sees(with_whole):
    policy = _policy(48, with_whole).train()
    g = torch.Generator().manual_seed(2)
    objects = torch.rand(4, 40, 3, generator=g) * 0.1
    batch = {OBJECT_KEY: objects, SCENE_KEY: torch.rand(4, 200, 3, generator=g), ACTION_KEY: objects + 0.3}
    loss, terms = policy.forward(batch)
    loss.backward()
    policy.update()
    assert torch.isfinite(loss) and terms["loss_local"] > 0
    assert all(p.grad is not None for p in policy.model.local_stage.parameters() if p.requires_grad)
    goals = policy.eval().sample_goals(objects[:2], batch[SCENE_KEY][:2], 5)
    assert goals.shape == (2, 5, 40, 3) and torch.isfinite(goals).all()


def test_a_negative_local_scene_size_is_refused_with_its_name():
    with pytest.raises(ValueError, match="local_scene_points"):
        TaxDPDConfig.for_point_clouds(32, 64, local_scene_points=-1)
