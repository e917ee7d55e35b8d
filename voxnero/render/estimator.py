"""Monte Carlo estimator of the rendering equation at surface points (stage 2's renderer).

    L_o(x, v) = integral over the sphere of f_r(n, v, l) L_i(x, l) max(n.l, 0) dl

with L_i = env(l) where ``visibility(x, l)`` says the ray escapes, else ``indirect(x, l)`` (or 0).
Directions come from up to three strategies -- cosine-weighted hemisphere, GGX visible normals
(``sampling.py``) and the env map's luminance (``EnvMap.sample``) -- combined by multi-sample
multiple importance sampling (Veach's power heuristic by default):

    L_o ~= sum_k 1/n_k sum_i w_k(l_ki) f L_i cos / p_k(l_ki).

Gradients: sampled directions, pdfs and MIS weights are detached (they depend on roughness and
n through the samplers); the estimator stays unbiased for the value and gives an unbiased
estimate of the gradient of the integral w.r.t. albedo, metallic, roughness and the radiance
(e.g. a learnable env map seen through ``env``).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from voxnero.render.brdf import brdf_eval, roughness_to_alpha, safe_normalize
from voxnero.render.envmap import EnvMap
from voxnero.render.sampling import (
    pdf_cosine,
    pdf_ggx_vndf,
    power_heuristic,
    sample_cosine,
    sample_ggx_vndf,
)

Radiance = Callable[[Tensor], Tensor]
Visibility = Callable[[Tensor, Tensor], Tensor]
Indirect = Callable[[Tensor, Tensor], Tensor]

STRATEGIES = ("mis", "balance", "cosine", "ggx", "env")


def _split(n_samples: int, names: list[str]) -> dict[str, int]:
    k = len(names)
    base = [n_samples // k] * k
    for i in range(n_samples - sum(base)):
        base[i] += 1
    return dict(zip(names, base, strict=True))


def shade_mc(
    x: Tensor,
    n: Tensor,
    v: Tensor,
    albedo: Tensor,
    metallic: Tensor,
    roughness: Tensor,
    env: EnvMap | Radiance,
    n_samples: int,
    visibility: Visibility | None = None,
    indirect: Indirect | None = None,
    strategy: str = "mis",
    generator: torch.Generator | None = None,
    ray_offset: float = 1e-4,
) -> Tensor:
    """Outgoing radiance toward v at surface points by MIS Monte Carlo.

    Args:
        x: (N, 3) surface points (world, unit-sphere frame).
        n: (N, 3) unit shading normals.
        v: (N, 3) unit directions toward the viewer (away from the surface).
        albedo: (N, 3) linear base colour.
        metallic: (N, 1) metalness.
        roughness: (N, 1) perceptual roughness (alpha = r^2).
        env: ``EnvMap`` (lookup + importance sampling) or a callable (M, 3) dirs -> (M, 3)
            linear radiance (then only cosine and GGX samples are used).
        n_samples: directions per point, split evenly over the strategies in use.
        visibility: optional callable (origins (M, 3), dirs (M, 3)) -> (M,) bool, True where
            the ray escapes to the environment. Origins are x + ray_offset * n.
        indirect: optional callable (origins (M, 3), dirs (M, 3)) -> (M, 3) radiance arriving
            along occluded directions (default 0).
        strategy: "mis" (power heuristic over all strategies), "balance" (balance heuristic),
            or a single strategy "cosine", "ggx", "env".
        generator: torch random generator (for reproducible estimates).
        ray_offset: distance along n by which ray origins are lifted off the surface.

    Returns:
        (N, 3) linear radiance.
    """
    if strategy not in STRATEGIES:
        from voxnero.errors import ConfigError

        raise ConfigError(f"unknown shading strategy {strategy!r}", fix=f"use one of {STRATEGIES}")
    has_env_sampler = isinstance(env, EnvMap)
    if strategy == "env" and not has_env_sampler:
        from voxnero.errors import ConfigError

        raise ConfigError("strategy='env' needs an EnvMap", fix="pass an EnvMap or use 'mis'")
    lookup: Radiance = env.lookup if has_env_sampler else env
    names = ["cosine", "ggx"] + (["env"] if has_env_sampler else [])
    if strategy in ("cosine", "ggx", "env"):
        names = [strategy]
    counts = _split(n_samples, names)
    names = [s for s in names if counts[s] > 0]
    beta = 1.0 if strategy == "balance" else 2.0

    N = x.shape[0]
    dev, dt = x.device, x.dtype
    n = safe_normalize(n)
    v = safe_normalize(v)
    alpha = roughness_to_alpha(roughness).detach()  # (N, 1)
    gdev = generator.device if generator is not None else dev
    total = torch.zeros(N, 3, device=dev, dtype=albedo.dtype)

    for name in names:
        c = counts[name]
        u = torch.rand(N * c, 2, generator=generator, device=gdev).to(dev, dt)
        nn_ = n.detach().repeat_interleave(c, 0)
        vv = v.detach().repeat_interleave(c, 0)
        aa = alpha.repeat_interleave(c, 0)[:, 0]
        with torch.no_grad():
            if name == "cosine":
                l, _ = sample_cosine(u, nn_)
            elif name == "ggx":
                l, _ = sample_ggx_vndf(u, nn_, vv, aa)
            else:
                l, _ = env.sample(u)
                l = l.to(dev, dt)
            pdfs = [pdf_cosine(nn_, l) if "cosine" in names else None,
                    pdf_ggx_vndf(nn_, vv, l, aa) if "ggx" in names else None,
                    env.pdf(l).to(dt) if "env" in names else None]
            pdfs = torch.stack([p for p in pdfs if p is not None], -1)  # (M, K)
            k = names.index(name)
            w = power_heuristic(pdfs, [counts[s] for s in names], beta=beta)[:, k]
            p_self = pdfs[:, k]
            scale = torch.where(p_self > 0, w / (c * p_self.clamp_min(1e-30)),
                                torch.zeros_like(p_self))
            cos = (nn_ * l).sum(-1).clamp_min(0.0)
            scale = scale * cos
        li = lookup(l)
        if visibility is not None:
            active = scale > 0
            idx = torch.nonzero(active)[:, 0]
            if idx.numel() > 0:
                xo = x.detach().repeat_interleave(c, 0)[idx] + ray_offset * nn_[idx]
                vis = visibility(xo, l[idx]).to(torch.bool).to(dev)
                occl = idx[~vis]
                if indirect is not None and occl.numel() > 0:
                    ind = indirect(xo[~vis], l[occl]).to(li.dtype)
                    li = li.index_put((occl,), ind)
                elif occl.numel() > 0:
                    li = li.index_put((occl,), torch.zeros(occl.numel(), 3, dtype=li.dtype,
                                                           device=li.device))
        f = brdf_eval(n.repeat_interleave(c, 0), v.repeat_interleave(c, 0), l,
                      albedo.repeat_interleave(c, 0),
                      metallic.repeat_interleave(c, 0), roughness.repeat_interleave(c, 0))
        contrib = f * li * scale[:, None]
        total = total + contrib.reshape(N, c, 3).sum(1)
    return total
