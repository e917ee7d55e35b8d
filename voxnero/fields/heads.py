"""Small material heads: grid features → albedo, metallic, roughness.

A feature grid (``DenseGrid`` with ``feat_dim`` channels) stores local appearance; a two-layer
MLP maps a feature vector to the BRDF parameters of ``voxnero.render.brdf``: linear albedo in
[0, 1]³, metallic in [0, 1] and *perceptual* roughness r in [r_min, 1] (GGX uses α = r²).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from voxnero.render.microfacet import raw_from_roughness, roughness_from_raw


def mlp(n_in: int, hidden: int, n_out: int, layers: int = 2) -> nn.Sequential:
    """A plain ReLU MLP with ``layers`` hidden layers of width ``hidden``."""
    mods: list[nn.Module] = []
    d = n_in
    for _ in range(layers):
        mods += [nn.Linear(d, hidden), nn.ReLU(inplace=True)]
        d = hidden
    mods.append(nn.Linear(d, n_out))
    return nn.Sequential(*mods)


def _logit(p: float) -> float:
    return math.log(p / (1.0 - p))


class MaterialHead(nn.Module):
    """Features ``(N, F)`` → ``albedo (N, 3)``, ``metallic (N, 1)``, ``roughness (N, 1)``.

    Args:
        feat_dim: F.
        hidden: MLP width.
        r_min: smallest perceptual roughness.
        init_roughness, init_metallic, init_albedo: outputs at initialisation (zero features).
        metallic: False fixes metallic to 0 (dielectric-only scenes).
    """

    def __init__(self, feat_dim: int, hidden: int = 32, r_min: float = 0.02,
                 init_roughness: float = 0.4, init_metallic: float = 0.3,
                 init_albedo: float = 0.4, metallic: bool = True):
        super().__init__()
        self.net = mlp(feat_dim, hidden, 5, layers=1)
        self.r_min = r_min
        self.use_metallic = metallic
        with torch.no_grad():
            last = self.net[-1]
            last.weight.mul_(0.1)
            last.bias.copy_(torch.tensor([_logit(init_albedo)] * 3
                                         + [_logit(init_metallic),
                                            raw_from_roughness(init_roughness, r_min)]))

    def forward(self, feat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        out = self.net(feat)
        albedo = torch.sigmoid(out[:, :3])
        metallic = torch.sigmoid(out[:, 3:4])
        if not self.use_metallic:
            metallic = torch.zeros_like(metallic)
        rough = roughness_from_raw(out[:, 4:5], self.r_min)
        return albedo, metallic, rough
