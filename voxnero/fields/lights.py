"""Learned light models: the explicit learnable env map (direct light, both stages), and stage 1's
indirect-light net and occlusion net.

Light arriving along a reflected direction ``r`` at a surface point ``x`` is, as in NeRO,
``L = (1 − s)·L_direct(r) + s·L_indirect(x, r)`` with occlusion probability ``s(x, r)``.

* :class:`EnvLight` — the direct light is one equirectangular map of log radiance (+Z up, the
  mapping of :mod:`voxnero.render.latlong`), used by stage 1 three ways: (1) the background of
  every ray (a distant environment: the background pixel *is* the light along the ray), (2) specular
  reflections, pre-filtered by roughness through a mip chain, (3) diffuse light from its
  cosine convolution (``irradiance``: order-2 SH, or the exact table of
  ``render.envmap.irradiance_table``). The DESIGN probe measured this explicit map better
  than a free colour net; it is also directly exportable. Stage 2 starts one from the photos'
  background pixels (:func:`voxnero.material.lights.init_from_background`), with a wider clamp,
  and looks it up and samples it in its Monte Carlo estimator.
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
from voxnero.render import latlong, mip, sh
from voxnero.render.envmap import irradiance_table


class EnvLight(nn.Module):
    """Learnable equirectangular env map of log radiance ``(H, 2H, 3)``: the direct light of both
    stages (stage 1: background, mip-filtered specular light, SH diffuse light; stage 2: the
    map its Monte Carlo estimator looks up and samples, exported as ``envmap.exr``).

    Args:
        height: H (the map starts uniform at ``init``; :meth:`from_image` starts from a map).
        init: initial linear radiance (uniform).
        max_log: upper clamp of the log radiance (numerical safety; stage 1 uses
            ``light.max_log_radiance`` = 4, stage 2 ``material.lights.LOG_MAX`` = 8).
        levels: mip levels of the roughness pre-filter chain (None: down to 2 rows, so that
            roughness 1 reaches its level, see ``mip.roughness_to_level``).
        min_log: lower clamp of the log radiance (None: none, stage 1; stage 2 uses
            ``material.lights.LOG_MIN`` = -12).
        irradiance: how :meth:`diffuse` convolves the map: "sh9" (order-2 SH, rings around a
            sun) or "exact" (``render.envmap.irradiance_table``).
    """

    def __init__(self, height: int = 64, init: float = 0.5, max_log: float = 4.0,
                 levels: int | None = None, min_log: float | None = None,
                 irradiance: str = "sh9"):
        super().__init__()
        self.log_radiance = nn.Parameter(torch.full((height, 2 * height, 3), math.log(init)))
        self.max_log = max_log
        self.min_log = min_log
        self.levels = levels
        if irradiance not in ("sh9", "exact"):
            raise ValueError(f"irradiance must be 'sh9' or 'exact', not {irradiance!r}")
        self.irradiance = irradiance
        self._chain: list[torch.Tensor] | None = None
        self._sh: torch.Tensor | None = None
        self._irr: torch.Tensor | None = None

    @classmethod
    def from_image(cls, image: torch.Tensor, max_log: float, min_log: float | None = None,
                   levels: int | None = None, irradiance: str = "sh9") -> EnvLight:
        """An env light starting from a linear map.

        Args:
            image: ``(H, 2H, 3)`` initial linear radiance (values below 1e-4 start at 1e-4).
            max_log, min_log, levels, irradiance: as for the constructor.
        """
        env = cls(int(image.shape[0]), 1.0, max_log, levels, min_log, irradiance)
        env.log_radiance = nn.Parameter(torch.log(image.float().clamp_min(1e-4)))
        return env

    @property
    def height(self) -> int:
        """H of the ``(H, 2H, 3)`` map."""
        return int(self.log_radiance.shape[0])

    def image(self) -> torch.Tensor:
        """The env map as linear radiance ``(H, W, 3)`` (differentiable)."""
        return torch.exp(self.log_radiance.clamp(self.min_log, self.max_log))

    def prepare(self) -> None:
        """Build the mip chain and the irradiance (SH coefficients or the exact table) of the
        current map (once per step)."""
        img = self.image()
        self._chain = mip.mip_chain(img, self.levels)
        if self.irradiance == "exact":
            self._irr = irradiance_table(img)
        else:
            self._sh = sh.sh9_project(img)

    def release(self) -> None:
        """Drop the per-step caches (so a stale graph is never reused)."""
        self._chain = None
        self._sh = None
        self._irr = None

    def background(self, d: torch.Tensor) -> torch.Tensor:
        """Radiance ``(N, 3)`` seen along unit directions ``d (N, 3)`` (finest level)."""
        return latlong.envmap_lookup(self.image() if self._chain is None else self._chain[0], d)

    def specular(self, d: torch.Tensor, roughness: torch.Tensor) -> torch.Tensor:
        """Pre-filtered radiance ``(N, 3)`` along ``d (N, 3)`` for perceptual roughness
        ``(N, 1)``."""
        if self._chain is None:
            self.prepare()
        return mip.lookup_rough(self._chain, d, roughness)

    def diffuse(self, n: torch.Tensor) -> torch.Tensor:
        """Cosine-weighted radiance ``E(n)/π`` ``(N, 3)`` for unit normals ``n (N, 3)``; a
        Lambertian surface of albedo a reflects ``a·E/π``."""
        if self._sh is None and self._irr is None:
            self.prepare()
        if self._irr is not None:
            return latlong.envmap_lookup(self._irr, n) / math.pi
        return sh.sh9_irradiance(self._sh, n) / math.pi

    def upsampled(self, height: int) -> EnvLight:
        """A new env light at ``height`` with the same clamps: the log map looked up (bilinear,
        same convention) at the new pixel-centre directions."""
        d = latlong.pixel_dirs(height, 2 * height, device=self.log_radiance.device)
        img = torch.exp(latlong.envmap_lookup(self.log_radiance.detach(), d))
        return EnvLight.from_image(img, self.max_log, self.min_log, self.levels, self.irradiance)

    def smoothness(self) -> torch.Tensor:
        """Mean squared difference of neighbouring log-radiance pixels (periodic in u)."""
        lr = self.log_radiance
        dx = lr - torch.roll(lr, 1, dims=1)
        dy = lr[1:] - lr[:-1]
        return (dx**2).mean() + (dy**2).mean()


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
