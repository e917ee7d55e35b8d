"""A near background: a low-resolution density + colour grid outside the region of interest.

Real captures put the object on a table in a room: the background is not at infinity, so one
radiance per direction (the env map) cannot draw it, and stage 1 then carves the table and the
room into the SDF or fails to carve at all. This field draws what lies *outside* the unit sphere
(the region of interest, where the SDF lives) and is composited behind the object; whatever it
leaves transparent is the env map's (a distant environment), and the env map alone still lights
the object.

Space is mip-NeRF 360's contraction (Barron et al. 2022)::

    contract(x) = x                         |x| <= 1
                  (2 - 1 / |x|) x / |x|     |x| >  1

which maps everything outside the unit sphere into the shell 1 < |x'| < 2; a dense grid over
``[-2, 2]³`` (``res``³ corners, ``grid_sample`` with ``align_corners=True``) holds a raw density
and a raw linear colour at every corner (density = softplus, colour = sigmoid).

Samples along a ray ``o + t d`` start at ``t0`` (where the ray leaves the unit sphere, or its
closest approach to the centre for a ray that misses it) and are spaced uniformly in disparity,
``t_k = t0 / u_k`` with ``u`` from 1 down to ``1 / far_ratio``; the opacity of the interval
between samples is ``1 − exp(−σ · |Δ x'|)`` with the length measured in the contracted space, so
the far shells cost as little as the near ones. Compositing returns the radiance and the
transmittance left for the distant environment.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def contract(x: torch.Tensor) -> torch.Tensor:
    """mip-NeRF 360 contraction of points ``(..., 3)`` into the ball of radius 2."""
    n = x.norm(dim=-1, keepdim=True).clamp(min=1e-9)
    return torch.where(n <= 1.0, x, (2.0 - 1.0 / n) * x / n)


def start_depth(origins: torch.Tensor, dirs: torch.Tensor, radius: float = 1.0) -> torch.Tensor:
    """``(R,)`` depth where each ray leaves the sphere of ``radius`` (its closest approach to the
    centre if it misses; never behind the origin).

    Args:
        origins: ``(R, 3)``; dirs: ``(R, 3)`` unit directions.
    """
    b = (origins * dirs).sum(-1)
    c = (origins * origins).sum(-1) - radius * radius
    disc = b * b - c
    far = -b + torch.sqrt(disc.clamp(min=0.0))
    return torch.where(disc > 0, far, -b).clamp(min=1e-3)


def disparity_samples(t0: torch.Tensor, n: int, far_ratio: float, jitter: bool = False,
                      generator: torch.Generator | None = None) -> torch.Tensor:
    """``(R, n + 1)`` depths from ``t0`` to ``t0 · far_ratio``, uniform in disparity.

    Args:
        t0: ``(R,)`` start depths (> 0).
        n: intervals per ray.
        far_ratio: last depth over the first.
        jitter: stratified jitter of the inner edges (training).
    """
    u = torch.linspace(0.0, 1.0, n + 1, device=t0.device)
    u = u.expand(t0.shape[0], n + 1).clone()
    if jitter:
        r = torch.rand(t0.shape[0], n - 1, device=t0.device, generator=generator) - 0.5
        u[:, 1:-1] = u[:, 1:-1] + r / n
    disp = 1.0 + u * (1.0 / far_ratio - 1.0)  # 1 -> 1 / far_ratio
    return t0[:, None] / disp


class NearBackground(nn.Module):
    """Density + colour grid over the contracted space outside the unit sphere.

    Args:
        res: grid corners per axis over ``[-2, 2]³``.
        samples: intervals per ray.
        far_ratio: depth of the last sample over the first (the rest is the env map's).
        init_density: density (per contracted unit length) everywhere at the start.
    """

    def __init__(self, res: int = 48, samples: int = 16, far_ratio: float = 64.0,
                 init_density: float = 1.0):
        super().__init__()
        raw = torch.zeros(4, res, res, res)
        raw[0] = float(torch.log(torch.expm1(torch.tensor(init_density))))  # softplus^-1
        self.grid = nn.Parameter(raw)
        self.samples, self.far_ratio = samples, far_ratio

    def query(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Density ``(N,)`` and linear colour ``(N, 3)`` at world points ``(N, 3)``."""
        xc = contract(x) / 2.0  # [-1, 1]³
        v = F.grid_sample(self.grid[None], xc.view(1, 1, 1, -1, 3), mode="bilinear",
                          padding_mode="border", align_corners=True)[0, :, 0, 0].T
        return F.softplus(v[:, 0]), torch.sigmoid(v[:, 1:])

    def forward(self, origins: torch.Tensor, dirs: torch.Tensor, jitter: bool = False,
                generator: torch.Generator | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Composite the field along rays.

        Args:
            origins: ``(R, 3)`` unit-frame ray origins; dirs: ``(R, 3)`` unit directions.
            jitter: stratified jitter of the samples (training).

        Returns:
            ``rgb (R, 3)`` linear radiance of the field and ``transmittance (R,)`` left for
            what lies beyond (the distant environment).
        """
        t = disparity_samples(start_depth(origins, dirs), self.samples, self.far_ratio, jitter,
                              generator)
        x = origins[:, None] + t[..., None] * dirs[:, None]  # (R, n+1, 3)
        xc = contract(x)
        seg = (xc[:, 1:] - xc[:, :-1]).norm(dim=-1)  # (R, n) contracted lengths
        mid = 0.5 * (x[:, 1:] + x[:, :-1])
        sigma, col = self.query(mid.reshape(-1, 3))
        alpha = 1.0 - torch.exp(-sigma.view(seg.shape) * seg)
        trans = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha + 1e-10],
                                        -1), -1)
        w = alpha * trans[:, :-1]
        rgb = (w[..., None] * col.view(*seg.shape, 3)).sum(1)
        return rgb, trans[:, -1]
