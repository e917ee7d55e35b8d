"""The Monte Carlo estimator of the rendering equation at surface points (the one estimator of
stage 2's training and evaluation renders and of relighting).

    L_o(x, v) = integral over the sphere of f_r(n, v, l) L_i(x, l) max(n.l, 0) dl

with L_i = env(l) where ``visibility(o, l)`` says the secondary ray escapes, else
``indirect(o, l)`` (the radiance of the surface it hits: a traced bounce, a cached or split-sum
estimate, see ``voxnero.material.render``) or 0. Directions come from up to three strategies --
cosine-weighted hemisphere, GGX visible normals (``sampling.py``) and the env map's luminance
(``EnvMap.sample``) -- combined by multi-sample multiple importance sampling (Veach 1997; power
heuristic by default)::

    L_o ~= sum_k 1/n_k sum_j w_k(l_kj) f L_i cos / p_k(l_kj),
    w_k = (n_k p_k)^b / sum_i (n_i p_i)^b   (b = 2 power, b = 1 balance heuristic).

Each strategy's uniform points are a Hammersley pattern shifted by a random toroidal offset per
point (Cranley-Patterson rotation): stratified and unbiased.

Gradients: sampled directions, pdfs and MIS weights are detached (they depend on roughness and
n through the samplers); the estimator stays unbiased for the value and gives an unbiased
estimate of the gradient of the integral w.r.t. albedo, metallic, roughness and the radiance
(e.g. a learnable env map looked up by ``env``, or the material at a traced bounce).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from torch import Tensor

from voxnero.render.brdf import brdf_eval
from voxnero.render.envmap import EnvMap
from voxnero.render.microfacet import roughness_to_alpha, safe_normalize
from voxnero.render.sampling import (
    pdf_cosine,
    pdf_ggx_vndf,
    power_heuristic,
    sample_cosine,
    sample_ggx_vndf,
)
from voxnero.render.splitsum import hammersley

Radiance = Callable[[Tensor], Tensor]
Visibility = Callable[[Tensor, Tensor], Tensor]
Indirect = Callable[[Tensor, Tensor], Tensor]
Spawn = Callable[[Tensor, Tensor], Tensor]

STRATEGIES = ("mis", "balance", "cosine", "ggx", "env")


def split_counts(n_samples: int, strategy: str, has_sampler: bool) -> tuple[int, int, int]:
    """Samples per strategy (cosine, GGX, env) for ``n_samples`` directions.

    "mis" / "balance" split them evenly over cosine, GGX and (with an env sampler) env, the
    first strategies taking the remainder; a single strategy takes all of them.
    """
    if strategy in ("cosine", "ggx", "env"):
        return tuple(n_samples if s == strategy else 0 for s in ("cosine", "ggx", "env"))
    k = 3 if has_sampler else 2
    base = [n_samples // k] * k
    for i in range(n_samples - sum(base)):
        base[i] += 1
    return (base[0], base[1], base[2] if has_sampler else 0)


def rotated_pattern(n_pts: int, n: int, generator: torch.Generator | None,
                    device: torch.device | str = "cpu") -> Tensor:
    """Hammersley pattern of n points, randomly shifted (mod 1) per point: (n_pts, n, 2)."""
    base = hammersley(n, dtype=torch.float32).to(device) if n > 1 else \
        torch.full((1, 2), 0.5, device=device)
    gdev = generator.device if generator is not None else torch.device("cpu")
    # drawn on the generator's device, then moved: the same stream on every shading device
    shift = torch.rand((n_pts, 1, 2), generator=generator, device=gdev).to(device)
    return torch.remainder(base[None] + shift, 1.0).clamp(0.0, 1.0 - 1e-7)


def sample_directions(n: Tensor, v: Tensor, alpha: Tensor, counts: Sequence[int],
                      sampler: EnvMap | None = None, generator: torch.Generator | None = None,
                      patterns: Sequence[Tensor | None] | None = None, beta: float = 2.0
                      ) -> tuple[Tensor, Tensor]:
    """Draw every strategy's directions and the MIS weight-over-pdf of each (all detached).

    Args:
        n: (N, 3) unit normals; v: (N, 3) unit view directions; alpha: (N, 1) GGX alpha.
        counts: samples per point of (cosine, GGX, env); env needs ``sampler``.
        sampler: env-map importance sampler, or None (no env samples).
        generator: random stream.
        patterns: optional uniform points per strategy, each (N, count, 2) or None, used
            instead of a fresh :func:`rotated_pattern`.
        beta: MIS heuristic exponent (2 power, 1 balance).

    Returns:
        l (N, S, 3) unit directions and wop (N, S) = w_k / (n_k p_k) of the strategy that drew
        each sample (0 where its pdf is 0).
    """
    n, v, alpha = n.detach(), v.detach(), alpha.detach()
    N = n.shape[0]
    counts = [int(counts[0]), int(counts[1]), int(counts[2]) if sampler is not None else 0]
    dirs, owner = [], []
    with torch.no_grad():
        for k, c in enumerate(counts):
            if c == 0:
                continue
            u = patterns[k] if patterns is not None and patterns[k] is not None else \
                rotated_pattern(N, c, generator, n.device)
            u = u.to(n.device, n.dtype).reshape(-1, 2)
            nk = n.repeat_interleave(c, 0)
            if k == 0:
                l, _ = sample_cosine(u, nk)
            elif k == 1:
                l, _ = sample_ggx_vndf(u, nk, v.repeat_interleave(c, 0),
                                       alpha.repeat_interleave(c, 0).reshape(-1))
            else:
                l, _ = sampler.sample(u)
                l = l.to(n.device, n.dtype)
            dirs.append(l.view(N, c, 3))
            owner += [k] * c
        l = torch.cat(dirs, 1)
        S = l.shape[1]
        lS = l.reshape(-1, 3)
        nS = n.repeat_interleave(S, 0)
        used = [k for k in range(3) if counts[k]]
        pdfs = []
        for k in used:
            if k == 0:
                pdfs.append(pdf_cosine(nS, lS))
            elif k == 1:
                pdfs.append(pdf_ggx_vndf(nS, v.repeat_interleave(S, 0), lS,
                                         alpha.repeat_interleave(S, 0).reshape(-1)))
            else:
                pdfs.append(sampler.pdf(lS).to(n.dtype).reshape(-1))
        pdfs = torch.stack(pdfs, -1)  # (N S, K)
        w = power_heuristic(pdfs, [counts[k] for k in used], beta=beta)
        own = torch.tensor([used.index(k) for k in owner], device=n.device).repeat(N)
        p_own = pdfs.gather(-1, own[:, None])[:, 0]
        w_own = w.gather(-1, own[:, None])[:, 0]
        c_own = torch.tensor([counts[k] for k in owner], device=n.device,
                             dtype=n.dtype).repeat(N)
        wop = torch.where(p_own > 0, w_own / (c_own * p_own.clamp_min(1e-30)),
                          torch.zeros_like(p_own))
    return l, wop.view(N, S)


def sample_one(n: Tensor, v: Tensor, alpha: Tensor, counts: Sequence[int],
               sampler: EnvMap | None = None, generator: torch.Generator | None = None,
               shares: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """One direction per point by one-sample MIS (Veach 1997, sec. 9.2.4): strategy k is
    chosen with probability q_k, and the sample weighs 1 / sum_k q_k p_k(l) (the balance
    heuristic; unbiased for any q that is > 0 wherever the integrand is). Used where paths
    must not branch (traced bounces).

    Args:
        n, v, alpha, counts, sampler, generator: as :func:`sample_directions` (all detached);
            q_k = c_k / sum(c) unless ``shares`` is given.
        shares: optional (N, 3) non-negative shares of (cosine, GGX, env) per point (e.g.
            from the material: a mirror draws GGX directions only); strategies whose count
            is 0 (or env without a sampler) get none.

    Returns:
        l (N, 1, 3) unit directions and wop (N, 1).
    """
    n, v, alpha = n.detach(), v.detach(), alpha.detach()
    N = n.shape[0]
    c = torch.tensor([float(counts[0] > 0), float(counts[1] > 0),
                      float(counts[2] > 0 and sampler is not None)], device=n.device,
                     dtype=n.dtype)
    base = torch.tensor([float(counts[0]), float(counts[1]),
                         float(counts[2]) if sampler is not None else 0.0], device=n.device,
                        dtype=n.dtype)
    q = base.expand(N, 3) if shares is None else shares.detach().to(n.dtype) * c
    q = torch.where(q.sum(-1, keepdim=True) > 0, q, base.expand(N, 3))
    q = q / q.sum(-1, keepdim=True)
    gdev = generator.device if generator is not None else torch.device("cpu")
    with torch.no_grad():
        u = torch.rand((N, 3), generator=generator, device=gdev).to(n.device, n.dtype)
        cq = torch.cumsum(q, -1)
        pick = (u[:, 2:3] >= cq[:, :2]).sum(-1)
        # float rounding at the top of the cumulative sum: never a strategy with no share
        pick = torch.where(q.gather(-1, pick[:, None])[:, 0] > 0, pick, q.argmax(-1))
        uv = u[:, :2].clamp(0.0, 1.0 - 1e-7)
        l = torch.zeros(N, 3, device=n.device, dtype=n.dtype)
        a = alpha.reshape(-1)
        for k in range(3):
            sel = (pick == k).nonzero()[:, 0]
            if sel.numel() == 0:
                continue
            if k == 0:
                l[sel] = sample_cosine(uv[sel], n[sel])[0]
            elif k == 1:
                l[sel] = sample_ggx_vndf(uv[sel], n[sel], v[sel], a[sel])[0]
            else:
                l[sel] = sampler.sample(uv[sel])[0].to(n.device, n.dtype)
        mix = torch.zeros(N, device=n.device, dtype=n.dtype)
        if c[0] > 0:
            mix = mix + q[:, 0] * pdf_cosine(n, l)
        if c[1] > 0:
            mix = mix + q[:, 1] * pdf_ggx_vndf(n, v, l, a)
        if c[2] > 0:
            mix = mix + q[:, 2] * sampler.pdf(l).to(n.dtype).reshape(-1)
        wop = torch.where(mix > 0, 1.0 / mix.clamp_min(1e-30), torch.zeros_like(mix))
    return l[:, None], wop[:, None]


def shade_mc(
    x: Tensor,
    n: Tensor,
    v: Tensor,
    albedo: Tensor,
    metallic: Tensor,
    roughness: Tensor,
    env: EnvMap | Radiance,
    n_samples: int = 0,
    visibility: Visibility | None = None,
    indirect: Indirect | None = None,
    strategy: str = "mis",
    generator: torch.Generator | None = None,
    ray_offset: float = 1e-4,
    *,
    counts: Sequence[int] | None = None,
    sampler: EnvMap | None = None,
    patterns: Sequence[Tensor | None] | None = None,
    spawn: Spawn | None = None,
    one_sample: bool = False,
    shares: Tensor | None = None,
    diffuse: str = "weighted",
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
            linear radiance (differentiable, e.g. a learnable map).
        n_samples: directions per point, split over the strategies by :func:`split_counts`
            (ignored when ``counts`` is given).
        visibility: optional callable (origins (M, 3), dirs (M, 3)) -> (M,) bool, True where
            the ray escapes to the environment.
        indirect: optional callable (origins (M, 3), dirs (M, 3)) -> (M, 3) radiance arriving
            along occluded directions (default 0).
        strategy: "mis" (power heuristic over all strategies), "balance" (balance heuristic),
            or a single strategy "cosine", "ggx", "env".
        generator: torch random generator (for reproducible estimates).
        ray_offset: distance along n by which ray origins are lifted off the surface (when no
            ``spawn`` is given).
        counts: samples per point of (cosine, GGX, env), instead of ``n_samples``/``strategy``.
        sampler: env-map importance sampler (default ``env`` if it is an ``EnvMap``; none: no
            env samples).
        patterns: uniform points per strategy, see :func:`sample_directions`.
        spawn: optional callable (point index (M,), dirs (M, 3)) -> (M, 3) ray origins (e.g. an
            offset along the face normal on the side of the ray).
        one_sample: draw ONE direction per point, its strategy chosen in proportion to
            ``counts`` (:func:`sample_one`), instead of all of them: a path that does not
            branch (traced bounces).
        shares: with ``one_sample``, optional (N, 3) shares of the strategies per point
            (:func:`sample_one`).
        diffuse: the BRDF's diffuse convention (``brdf.DIFFUSE_MODELS``).

    Returns:
        (N, 3) linear radiance.
    """
    from voxnero.errors import ConfigError

    if strategy not in STRATEGIES:
        raise ConfigError(f"unknown shading strategy {strategy!r}", fix=f"use one of {STRATEGIES}")
    if sampler is None and isinstance(env, EnvMap):
        sampler = env
    if strategy == "env" and sampler is None:
        raise ConfigError("strategy='env' needs an EnvMap", fix="pass an EnvMap or use 'mis'")
    lookup: Radiance = env.lookup if isinstance(env, EnvMap) else env
    if counts is None:
        counts = split_counts(n_samples, strategy, sampler is not None)
    beta = 1.0 if strategy == "balance" else 2.0
    N = x.shape[0]
    if N == 0 or sum(counts[:2]) + (counts[2] if sampler is not None else 0) == 0:
        return torch.zeros(N, 3, device=x.device, dtype=albedo.dtype)

    n = safe_normalize(n)
    v = safe_normalize(v)
    alpha = roughness_to_alpha(roughness.detach())
    if one_sample:
        l, wop = sample_one(n, v, alpha, counts, sampler, generator, shares)
    else:
        l, wop = sample_directions(n, v, alpha, counts, sampler, generator, patterns, beta)
    S = l.shape[1]
    lf = l.reshape(-1, 3)
    with torch.no_grad():
        cos = (n.detach()[:, None] * l).sum(-1).clamp_min(0.0)
        scale = (wop * cos).reshape(-1)
    li = lookup(lf)
    if visibility is not None:
        idx = torch.nonzero(scale > 0)[:, 0]
        if idx.numel() > 0:
            pt = torch.div(idx, S, rounding_mode="floor")
            if spawn is not None:
                xo = spawn(pt, lf[idx])
            else:
                xo = x.detach()[pt] + ray_offset * n.detach()[pt]
            vis = visibility(xo, lf[idx]).to(torch.bool).to(x.device)
            occl = idx[~vis]
            if occl.numel() > 0:
                if indirect is not None:
                    val = indirect(xo[~vis], lf[occl]).to(li.dtype)
                else:
                    val = torch.zeros(occl.numel(), 3, dtype=li.dtype, device=li.device)
                li = li.index_put((occl,), val)
    f = brdf_eval(n.repeat_interleave(S, 0), v.repeat_interleave(S, 0), lf,
                  albedo.repeat_interleave(S, 0), metallic.repeat_interleave(S, 0),
                  roughness.repeat_interleave(S, 0), diffuse)
    return (f * li * scale[:, None]).view(N, S, 3).sum(1)
