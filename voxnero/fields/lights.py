"""Stage-1 light models: an explicit learnable env map (direct light), an indirect-light net and
an occlusion net.

Light arriving along a reflected direction ``r`` at a surface point ``x`` is, as in NeRO,
``L = (1 − s)·L_direct(r) + s·L_indirect(x, r)`` with occlusion probability ``s(x, r)``.

* :class:`EnvLight` — the direct light is one equirectangular map of log radiance (+Z up, the
  mapping of :mod:`voxnero.render.envmap`), used three ways: (1) the background of every ray
  (a distant environment: the background pixel *is* the light along the ray), (2) specular
  reflections, pre-filtered by roughness through a mip chain, (3) diffuse light from its
  order-2 SH projection (cosine convolution). The DESIGN probe measured this explicit map better
  than a free colour net; it is also directly exportable.
* :class:`IndirectNet` — radiance that a reflected ray picks up from the object itself, a small
  MLP on grid features at ``x`` and the direction ``r`` (linear radiance ≥ 0). (Stage 2's
  analytic counterpart is :class:`voxnero.material.lights.IndirectLight`.)
* :class:`OcclusionNet` — ``s(x, r)`` in [0, 1], supervised by ray casts against the current
  mesh (:mod:`voxnero.shape.occlusion`).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from voxnero.fields.heads import mlp
from voxnero.render import envmap


class EnvLight(nn.Module):
    """Learnable equirectangular env map of log radiance ``(H, 2H, 3)``.

    Args:
        height: H.
        init: initial linear radiance (uniform).
        max_log: upper clamp of the log radiance (numerical safety).
        levels: mip levels of the roughness pre-filter chain (None: down to 2 rows, so that
            roughness 1 reaches its level, see ``envmap.roughness_to_level``).
    """

    def __init__(self, height: int = 64, init: float = 0.5, max_log: float = 4.0,
                 levels: int | None = None):
        super().__init__()
        self.log_radiance = nn.Parameter(torch.full((height, 2 * height, 3), math.log(init)))
        self.max_log = max_log
        self.levels = levels
        self._chain: list[torch.Tensor] | None = None
        self._sh: torch.Tensor | None = None

    def image(self) -> torch.Tensor:
        """The env map as linear radiance ``(H, W, 3)``."""
        return torch.exp(self.log_radiance.clamp(max=self.max_log))

    def prepare(self) -> None:
        """Build the mip chain and SH coefficients of the current map (once per step)."""
        img = self.image()
        self._chain = envmap.mip_chain(img, self.levels)
        self._sh = envmap.sh9_project(img)

    def release(self) -> None:
        """Drop the per-step caches (so a stale graph is never reused)."""
        self._chain = None
        self._sh = None

    def background(self, d: torch.Tensor) -> torch.Tensor:
        """Radiance ``(N, 3)`` seen along unit directions ``d (N, 3)`` (finest level)."""
        return envmap.envmap_lookup(self.image() if self._chain is None else self._chain[0], d)

    def specular(self, d: torch.Tensor, roughness: torch.Tensor) -> torch.Tensor:
        """Pre-filtered radiance ``(N, 3)`` along ``d (N, 3)`` for perceptual roughness
        ``(N, 1)``."""
        if self._chain is None:
            self.prepare()
        return envmap.lookup_rough(self._chain, d, roughness)

    def diffuse(self, n: torch.Tensor) -> torch.Tensor:
        """Cosine-weighted radiance ``E(n)/π`` ``(N, 3)`` for unit normals ``n (N, 3)``; a
        Lambertian surface of albedo a reflects ``a·E/π``."""
        if self._sh is None:
            self.prepare()
        return envmap.sh9_irradiance(self._sh, n) / math.pi


class IndirectNet(nn.Module):
    """Radiance ``(N, 3)`` reflected toward ``x`` by the object along ``r``, from features.

    Args:
        feat_dim: feature size at ``x``.
        hidden: MLP width.
    """

    def __init__(self, feat_dim: int, hidden: int = 32):
        super().__init__()
        self.net = mlp(feat_dim + 4, hidden, 3, layers=2)
        with torch.no_grad():
            self.net[-1].bias.fill_(math.log(0.3))

    def forward(self, feat: torch.Tensor, d: torch.Tensor, roughness: torch.Tensor
                ) -> torch.Tensor:
        """Args: feat ``(N, F)``, d ``(N, 3)`` unit, roughness ``(N, 1)``. Returns ``(N, 3)``."""
        out = self.net(torch.cat([feat, d, roughness], -1))
        return torch.exp(out.clamp(max=4.0))


class OcclusionNet(nn.Module):
    """Probability ``(N, 1)`` that a ray from ``x`` along ``d`` hits the object itself."""

    def __init__(self, feat_dim: int, hidden: int = 32):
        super().__init__()
        self.net = mlp(feat_dim + 3, hidden, 1, layers=2)
        with torch.no_grad():
            self.net[-1].bias.fill_(-3.0)

    def forward(self, feat: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """Args: feat ``(N, F)``, d ``(N, 3)`` unit. Returns ``(N, 1)`` in (0, 1)."""
        return torch.sigmoid(self.net(torch.cat([feat, d], -1)))
