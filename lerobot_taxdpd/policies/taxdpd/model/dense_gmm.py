"""Global placement initialisation: a Dense GMM with one Gaussian per scene point.

Scene tokens (PointNet++ features of the scene) cross-attend to object tokens in a DiT conditioned on the
object-to-scene offset (the diffusion step is fixed at 0, so a learned vector replaces its embedding).
Each scene point i gets a mixing logit and a residual r_i; the component mean is p_i + r_i. Trained by the
negative log-likelihood of the true goal centroid under isotropic Gaussians of fixed variance.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from lerobot_taxdpd.policies.taxdpd.model.dit import DiT, OutputHead
from lerobot_taxdpd.policies.taxdpd.model.pointnet2 import Grouping, SamplingLayout, make_encoder


class DenseGMM(nn.Module):
    def __init__(self, config) -> None:
        super().__init__()
        dim = config.hidden_dim
        self.variance = config.gmm_variance
        self.uniform_weight = config.gmm_uniform_weight
        self.object_encoder = make_encoder(config, in_channels=0)
        self.scene_encoder = make_encoder(config, in_channels=0)
        self.condition = nn.Parameter(torch.zeros(dim))
        self.offset_embedding = nn.Sequential(nn.Linear(3, dim), nn.SiLU(), nn.Linear(dim, dim))
        self.backbone = DiT(dim, config.num_heads, config.num_blocks, config.mlp_ratio)
        self.head = OutputHead(dim, 4)

    def forward(
        self,
        object_centred: Tensor,
        scene_centred: Tensor,
        offset: Tensor,
        layouts: list[SamplingLayout] | None = None,
        object_grouping: Grouping | None = None,
    ) -> tuple[Tensor, Tensor]:
        """object_centred (B, N, 3), scene_centred (B, M, 3), offset = object centroid - scene centroid (B, 3);
        `layouts`: the object's and the scene's FPS layouts, `object_grouping` the object's grouping, when the
        caller shares them with the local stage.

        Returns mixing logits (B, M) and component means (B, M, 3) in the scene-centred frame.
        """
        object_layout, scene_layout = layouts if layouts is not None else (None, None)
        object_tokens = self.object_encoder(
            object_centred,
            object_centred.new_zeros(*object_centred.shape[:2], 0),
            layout=object_layout,
            grouping=object_grouping,
        )
        condition = self.condition + self.offset_embedding(offset)
        scene_tokens = self.scene_encoder(
            scene_centred, scene_centred.new_zeros(*scene_centred.shape[:2], 0), layout=scene_layout
        )
        out = self.head(self.backbone(scene_tokens, object_tokens, condition), condition).float()
        return out[..., 0], scene_centred + out[..., 1:]

    def climb_to_modes(self, start: Tensor, weights: Tensor, means: Tensor, iterations: int = 10) -> Tensor:
        """Points (B, K, 3) moved uphill to the peaks of the mixture's density (weights (B, M), means (B, M, 3)).

        Mean shift with the components' own Gaussians: each step moves a point to the average of the means,
        each weighted by its mixing weight times its density at the point, which never lowers the density
        and converges to the peak whose basin holds the start. Started at sampled components' means, it
        sends every component of one slot to the same, most likely point of that slot."""
        points = start.float()
        means, weights = means.float(), weights.float()
        for _ in range(iterations):
            d2 = (points.unsqueeze(2) - means.unsqueeze(1)).square().sum(-1)  # (B, K, M)
            pull = weights.unsqueeze(1) * torch.exp(-0.5 * d2 / self.variance)
            points = (pull @ means) / pull.sum(-1, keepdim=True)
        return points

    def log_likelihood(self, logits: Tensor, means: Tensor, target: Tensor) -> Tensor:
        """log p(target) under the mixture: logsumexp_i [log w_i + log N(target; mean_i, var I)]  -> (B,)."""
        d2 = (means - target.unsqueeze(1)).square().sum(-1)
        log_gauss = -0.5 * d2 / self.variance - 1.5 * math.log(2 * math.pi * self.variance)
        return torch.logsumexp(torch.log_softmax(logits, -1) + log_gauss, dim=-1)

    def loss(self, logits: Tensor, means: Tensor, target: Tensor) -> Tensor:
        """NLL of the goal centroid, plus `uniform_weight` x the NLL with equal weights.

        The second term gives every component a gradient, so residuals stay useful where the weights are
        still small (otherwise a mode the weights missed early is never learnt).
        """
        nll = -self.log_likelihood(logits, means, target)
        uniform_nll = -self.log_likelihood(torch.zeros_like(logits), means, target)
        return (nll + self.uniform_weight * uniform_nll).mean()
