"""The encoder's set abstraction computes PointNet++'s layer: the shortcuts it takes for speed (the first layer
split into per-point and per-centroid parts, the last ReLU after the pooling, the pooling's argmax) change
neither its values nor its gradients."""

from __future__ import annotations

import torch

from lerobot_taxdpd.maths.geometry import gather_points
from lerobot_taxdpd.policies.taxdpd.model.pointnet2 import SetAbstraction


def textbook_set_abstraction(layer: SetAbstraction, xyz, features, centres, neighbors):
    """The per-pair form: an MLP with a ReLU after every layer on [p_j - c_i, f_j] of each ball, max-pooled."""
    relative = gather_points(xyz, neighbors) - centres.unsqueeze(-2)
    hidden = torch.cat([relative, gather_points(features, neighbors)], -1)
    for linear in (layer.first, *(m for m in layer.rest if isinstance(m, torch.nn.Linear))):
        hidden = torch.relu(linear(hidden))
    return hidden.amax(dim=-2)


def test_set_abstraction_equals_the_per_pair_mlp_in_values_and_gradients():
    torch.manual_seed(0)
    layer = SetAbstraction(5, (8, 8, 16)).double()
    xyz = torch.randn(2, 30, 3, dtype=torch.double)
    features = torch.randn(2, 30, 5, dtype=torch.double, requires_grad=True)
    centres = gather_points(xyz, torch.randint(0, 30, (2, 6)))
    neighbors = torch.randint(0, 30, (2, 6, 8))
    inputs = [features, *layer.parameters()]

    fast = layer(xyz, features, centres, neighbors)
    slow = textbook_set_abstraction(layer, xyz, features, centres, neighbors)
    fast_grads = torch.autograd.grad(fast.square().sum(), inputs)
    slow_grads = torch.autograd.grad(slow.square().sum(), inputs)

    torch.testing.assert_close(fast, slow)
    assert (slow > 0).any() and (slow == 0).any()  # both sides of the pooled ReLU are exercised
    for a, b in zip(fast_grads, slow_grads, strict=True):
        torch.testing.assert_close(a, b)
