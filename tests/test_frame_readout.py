"""`frame_from_points`: the frame's denoised value read from the frame token plus the mean of the point head's
outputs (which the shape's centring discards otherwise), so that every object token votes where the goal's
centroid goes."""

from __future__ import annotations

import pytest
import torch

from lerobot_taxdpd import TaxDPDConfig
from lerobot_taxdpd.policies.taxdpd.model.parameterizations import make_parameterization


@pytest.mark.parametrize("from_points", [False, True], ids=["token", "token-and-points"])
def test_the_point_outputs_mean_moves_the_frame_only_when_asked(from_points):
    config = TaxDPDConfig.for_point_clouds(32, 64, frame_from_points=from_points)
    g = torch.Generator().manual_seed(0)
    point_out, frame_out = torch.randn(2, 32, 3, generator=g) + 5.0, torch.randn(2, 3, generator=g)
    state = make_parameterization(config).split(point_out, frame_out)
    mean = point_out.mean(1, keepdim=True)
    torch.testing.assert_close(state["shape"], point_out - mean)  # the shape is centred either way
    expected = frame_out.unsqueeze(1) + (mean if from_points else 0.0)
    torch.testing.assert_close(state["frame"], expected)


@pytest.mark.parametrize("overrides", [dict(disentangled=False), dict(local_diffusion="se3")], ids=["joint", "se3"])
def test_a_model_without_a_frame_and_point_outputs_refuses_it(overrides):
    with pytest.raises(ValueError, match="frame_from_points: needs disentangled=true and local_diffusion='point'"):
        TaxDPDConfig.for_point_clouds(32, 64, frame_from_points=True, **overrides)
