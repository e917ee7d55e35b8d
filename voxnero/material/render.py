"""Rendering of surface points on the fixed mesh: the estimator plus the light paths on the mesh.

The integral at a surface point is the shading core's one Monte Carlo estimator
(:func:`voxnero.render.estimator.shade_mc`: cosine, GGX-VNDF and env-map samples, multi-sample
MIS with the power heuristic, rotated Hammersley patterns, material detached for sampling).
This module supplies what it needs from the mesh (Open3D, :class:`~voxnero.material.surface.
Geometry`): ray origins off the surface, visibility of every secondary ray (``test_occlusions``)
and the radiance arriving along a secondary ray that hits the object, as

* ``traced`` (:class:`Paths`): the ray is cast on the mesh and the hit is shaded with the
  learned material and light by the same estimator (``Bounces.traced`` inter-reflection
  bounces, then ``Bounces.rr`` more continued by Russian roulette), after which the split-sum
  estimate (:class:`voxnero.material.lights.IndirectLight`) or 0 ends the path;
* ``splitsum``: the split-sum estimate at the first secondary hit (no further casts);
* off: 0 (shadows only).

Stage 2's training and evaluation renders and ``voxnero relight`` all go through
:class:`Paths`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from voxnero.material.lights import IndirectLight
from voxnero.material.surface import Geometry
from voxnero.render.brdf import check_diffuse
from voxnero.render.envmap import EnvMap
from voxnero.render.estimator import rotated_pattern, shade_mc
from voxnero.render.estimator import sample_directions as _sample_directions
from voxnero.render.latlong import envmap_lookup

__all__ = ["Bounces", "Paths", "Strategies", "env_sampler", "rotated_pattern",
           "sample_directions", "shade"]


@dataclass
class Strategies:
    """Samples per point of each strategy."""

    cos: int = 8
    ggx: int = 8
    env: int = 8

    @property
    def total(self) -> int:
        return self.cos + self.ggx + self.env

    @property
    def counts(self) -> tuple[int, int, int]:
        return (self.cos, self.ggx, self.env)


@dataclass
class Bounces:
    """How light arriving along secondary rays that hit the object is estimated.

    Attributes:
        traced: inter-reflection bounces traced on the mesh and shaded with the estimator
            after the first surface interaction (0: the ``tail`` at the first secondary hit).
        rr: further bounces each continued with probability ``survive`` (Russian roulette,
            weight 1 / survive: unbiased) before the tail ends the path.
        survive: Russian-roulette survival probability.
        spp: samples per strategy at every secondary hit; with ``one_sample`` their shares
            of the ONE direction drawn there (one-sample MIS).
        one_sample: one direction per secondary hit: a path never branches, so a bounce
            costs one ray per path (stage 2); False: every strategy's samples (relight's
            ``bounce_dirs``).
    """

    traced: int = 2
    rr: int = 2
    survive: float = 0.5
    spp: Strategies = field(default_factory=lambda: Strategies(1, 1, 1))
    one_sample: bool = True


def env_sampler(image: Tensor) -> EnvMap:
    """The shading core's env-map importance sampler for a (detached) map.

    Args:
        image: (H, W, 3) linear map.

    Returns:
        An :class:`voxnero.render.envmap.EnvMap`: ``sample(u (N, 2)) -> (dirs (N, 3), pdf (N,))``
        and ``pdf(d) -> (N,)``.
    """
    return EnvMap(image.detach())


def sample_directions(n: Tensor, v: Tensor, alpha: Tensor, spp: Strategies, env=None,
                      generator: torch.Generator | None = None,
                      patterns: list[Tensor | None] | None = None
                      ) -> tuple[Tensor, Tensor, list[int]]:
    """:func:`voxnero.render.estimator.sample_directions` with a :class:`Strategies`.

    Returns:
        l (N, S, 3), wop (N, S) and the counts [n_cos, n_ggx, n_env] actually used.
    """
    counts = [spp.cos, spp.ggx, spp.env if env is not None else 0]
    l, wop = _sample_directions(n, v, alpha, counts, env, generator, patterns)
    return l, wop, counts


def material_shares(albedo: Tensor, metallic: Tensor, spp: Strategies) -> Tensor:
    """Shares of (cosine, GGX, env) of the one direction drawn at a secondary hit.

    In proportion to the lobes' reflectance at normal incidence: the diffuse lobe
    (1 − m)(1 − 0.04) mean(albedo) goes to the cosine and env strategies (in the ratio of
    ``spp``), the specular lobe mean(F0) to GGX; so a chrome hit draws GGX directions only
    (no wasted cosine or env samples on a mirror) and a matte one mostly cosine/env ones.

    Args:
        albedo: (N, 3); metallic: (N, 1); spp: the strategies' base counts.

    Returns:
        (N, 3) non-negative shares.
    """
    from voxnero.render.microfacet import DIELECTRIC_F0

    a = albedo.detach().mean(-1, keepdim=True)
    m = metallic.detach()
    spec = DIELECTRIC_F0 * (1 - m) + m * a
    diff = (1 - m) * (1 - DIELECTRIC_F0) * a
    tot = max(spp.cos + spp.env, 1)
    return torch.cat([diff * spp.cos / tot, spec * float(spp.ggx > 0), diff * spp.env / tot],
                     -1) + 1e-3


class Paths:
    """Light paths on a fixed mesh: shades surface points with :func:`shade_mc`, casting
    secondary rays with Open3D and estimating what they bring (see the module).

    Args:
        geom: the mesh (unit frame).
        material: ``(tri (N,), bary (N, 3), x (N, 3)) -> (albedo (N, 3), metallic (N, 1),
            roughness (N, 1))`` (e.g. the learnable field).
        radiance: ``(M, 3) dirs -> (M, 3)`` env radiance (differentiable for training).
        sampler: env-map importance sampler (detached), or None.
        mode: "traced", "splitsum" or "off" (occluded rays carry 0); None = no visibility casts
            at all (every secondary ray sees the env map).
        tail: the split-sum estimate ending traced paths (and the "splitsum" mode), or None (0).
        bounces: :class:`Bounces` of the "traced" mode.
        generator: random stream.
        strategy: :func:`shade_mc`'s MIS heuristic ("mis" power, "balance"); the counts per
            strategy are given to :meth:`shade`.
        diffuse: the BRDF's diffuse convention at every vertex of the paths
            (``voxnero.render.brdf.DIFFUSE_MODELS``).
    """

    def __init__(self, geom: Geometry, material, radiance, sampler: EnvMap | None,
                 mode: str | None, tail: IndirectLight | None = None,
                 bounces: Bounces | None = None, generator: torch.Generator | None = None,
                 strategy: str = "mis", diffuse: str = "weighted"):
        self.strategy = strategy
        self.diffuse = check_diffuse(diffuse)
        self.geom, self.material, self.radiance, self.sampler = geom, material, radiance, sampler
        self.mode, self.tail = mode, tail
        self.bounces = bounces or Bounces()
        self.gen = generator
        self.stats = {"secondary": 0, "hits": 0}

    @property
    def max_depth(self) -> int:
        return self.bounces.traced + self.bounces.rr

    def shade(self, tri: Tensor, bary: Tensor, x: Tensor, n: Tensor, v: Tensor,
              spp: Strategies, depth: int = 0,
              patterns: list[Tensor | None] | None = None) -> Tensor:
        """Outgoing radiance of surface points toward v.

        Args:
            tri: (N,) triangles; bary: (N, 3); x: (N, 3) points; n: (N, 3) unit shading
                normals; v: (N, 3) unit directions toward the viewer (or the previous vertex).
            spp: samples per strategy.
            depth: 0 for primary hits, k for the k-th inter-reflection bounce.
            patterns: uniform points per strategy (see ``sample_directions``).

        Returns:
            (N, 3) linear radiance.
        """
        g = self.geom
        albedo, metallic, roughness = self.material(tri, bary, x)
        # an interpolated normal may face away from the viewer (silhouettes, secondary hits):
        # bend it so that n.v >= 1e-3, else the BRDF is 0 there and such points turn black
        nv = (n * v).sum(-1, keepdim=True)
        n = torch.nn.functional.normalize(n + (1e-3 - nv).clamp_min(0.0) * v, dim=-1)
        visibility = indirect = spawn = None
        if self.mode is not None:
            def spawn(i: Tensor, d: Tensor) -> Tensor:
                return g.spawn(tri[i], x[i].detach(), d)

            def visibility(o: Tensor, d: Tensor) -> Tensor:
                return ~g.occluded(o, d)

            if self.mode == "traced":
                def indirect(o: Tensor, d: Tensor) -> Tensor:
                    return self.incoming(o, d, depth + 1)
            elif self.mode == "splitsum" and self.tail is not None:
                def indirect(o: Tensor, d: Tensor) -> Tensor:
                    return self._tail(o, d)
        one = depth > 0 and self.bounces.one_sample
        return shade_mc(x, n, v, albedo, metallic, roughness, self.radiance, 0, visibility,
                        indirect, "balance" if self.strategy == "balance" else "mis",
                        generator=self.gen, counts=spp.counts, sampler=self.sampler,
                        patterns=patterns, spawn=spawn, one_sample=one,
                        shares=material_shares(albedo, metallic, self.bounces.spp) if one
                        else None, diffuse=self.diffuse)

    def _hits(self, o: Tensor, d: Tensor):
        _, tri, bary = self.geom.cast(o, d)
        hit = tri >= 0
        self.stats["secondary"] += int(o.shape[0])
        self.stats["hits"] += int(hit.sum())
        return tri, bary, hit.nonzero()[:, 0]

    def _tail(self, o: Tensor, d: Tensor) -> Tensor:
        """Split-sum estimate of the radiance along rays that hit the mesh (env on a miss)."""
        tri, bary, idx = self._hits(o, d)
        out = self.radiance(d)
        if idx.numel() == 0:
            return out
        t, b = tri[idx], bary[idx]
        if self.tail is None:
            return out.index_put((idx,), torch.zeros(idx.numel(), 3, device=out.device,
                                                     dtype=out.dtype))
        a, m, r = self.material(t, b, self.geom.points_at(t, b))
        val = self.tail.radiance(self.geom.normals_at(t, b), -d[idx], a, m, r)
        return out.index_put((idx,), val.to(out.dtype))

    def incoming(self, o: Tensor, d: Tensor, depth: int) -> Tensor:
        """Radiance arriving at origins o from directions d (rays the visibility test found
        blocked): the hit shaded at bounce ``depth`` (with Russian roulette past
        ``bounces.traced``), the tail past the last bounce; env along rays that miss after all.

        Args:
            o: (M, 3) origins; d: (M, 3) unit directions; depth: bounce number (>= 1).

        Returns:
            (M, 3) linear radiance.
        """
        b = self.bounces
        if depth > self.max_depth:
            return self._tail(o, d)
        keep = None
        if depth > b.traced:  # Russian roulette: continue a fraction ``survive`` of the paths
            u = torch.rand(o.shape[0], generator=self.gen,
                           device=self.gen.device if self.gen is not None else "cpu")
            keep = (u < b.survive).to(o.device)
        tri, bary, idx = self._hits(o, d)
        out = self.radiance(d)
        if idx.numel() == 0:
            return out
        if keep is not None:
            dead = idx[~keep[idx]]
            idx = idx[keep[idx]]
            if dead.numel():
                out = out.index_put((dead,), torch.zeros(dead.numel(), 3, device=out.device,
                                                         dtype=out.dtype))
            if idx.numel() == 0:
                return out
        t, bb = tri[idx], bary[idx]
        x, n = self.geom.points_at(t, bb), self.geom.normals_at(t, bb)
        val = self.shade(t, bb, x, n, -d[idx], b.spp, depth)
        if keep is not None:
            val = val / b.survive
        return out.index_put((idx,), val.to(out.dtype))


def shade(geom: Geometry, field, env_image: Tensor, tri: Tensor, bary: Tensor, x: Tensor,
          n: Tensor, v: Tensor, spp: Strategies, indirect: IndirectLight | None = None,
          env=None, visibility: bool = True, generator: torch.Generator | None = None,
          patterns: list[Tensor | None] | None = None, bounces: Bounces | None = None,
          diffuse: str = "weighted") -> Tensor:
    """Outgoing radiance L_o(x, v) of surface points (see the module).

    Args:
        geom: the mesh (unit frame); field: material field ``(tri, bary, x) -> (albedo (N, 3),
            metallic (N, 1), roughness (N, 1))``.
        env_image: (H, W, 3) linear env map (differentiable).
        tri: (N,) triangles; bary: (N, 3) barycentrics; x: (N, 3) points; n: (N, 3) unit
            shading normals; v: (N, 3) unit directions toward the viewer.
        spp: samples per strategy.
        indirect: split-sum estimate of the radiance of secondary hits (ends traced paths), or
            None (0).
        env: env-map sampler for the env strategy (:func:`env_sampler`) or None.
        visibility: cast secondary rays (shadows / indirect); False treats all as escaping.
        generator: random stream.
        patterns: uniform points per strategy (see :func:`sample_directions`).
        bounces: trace inter-reflections on the mesh (:class:`Bounces`); None: the ``indirect``
            estimate at the first secondary hit.
        diffuse: the BRDF's diffuse convention (``voxnero.render.brdf.DIFFUSE_MODELS``).

    Returns:
        (N, 3) linear radiance.
    """
    if not visibility:
        mode = None
    elif bounces is not None:
        mode = "traced"
    else:
        mode = "splitsum" if indirect is not None else "off"
    paths = Paths(geom, field, lambda d: envmap_lookup(env_image, d), env, mode, indirect,
                  bounces, generator, diffuse=diffuse)
    return paths.shade(tri, bary, x, n, v, spp, 0, patterns)
