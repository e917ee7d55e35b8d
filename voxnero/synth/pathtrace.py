"""Monte Carlo path tracing of analytic scenes under a distant environment map.

Unidirectional path tracer, vectorised over all rays of a batch (torch, CPU or CUDA):

- primary rays that miss every object return the environment along the ray (the environment
  is at infinity, so the background pixel *is* the env map seen through the pixel);
- at every surface hit, next-event estimation samples the env map (``EnvMap.sample``) with an
  exact shadow ray, and the path continues in a direction drawn from the BRDF (a mixture of
  cosine and GGX visible-normal sampling, from :mod:`voxnero.render.sampling`); both strategies
  are combined by the power heuristic, so mirror-like and diffuse surfaces, small bright suns
  and broad skies all converge;
- the BRDF is the project's :func:`voxnero.render.brdf.brdf_eval` (Lambert + GGX, α = r²);
- ``max_depth`` counts surface interactions: 1 = direct lighting only (with shadows), 2 = one
  indirect bounce (two objects see each other in reflection), and so on. No Russian roulette
  (depths are small); paths whose throughput becomes zero stop early.

Radiance is linear (the env map's units). Randomness comes from a caller's ``torch.Generator``.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from voxnero.render.brdf import brdf_eval
from voxnero.render.microfacet import f0_from, fresnel_schlick, roughness_to_alpha
from voxnero.render.sampling import (
    pdf_cosine,
    pdf_ggx_vndf,
    power_heuristic,
    sample_cosine,
    sample_ggx_vndf,
)
from voxnero.synth.materials import MaterialTable
from voxnero.synth.shapes import Union

RAY_EPS = 1e-4
"""Secondary rays start this far (scene units) off the surface, along the normal."""

MIN_SPEC_PROB = 0.1
"""Lower bound of the probability of sampling the specular lobe (when there is a diffuse one)."""


def _mis(pdf_a: torch.Tensor, pdf_b: torch.Tensor) -> torch.Tensor:
    """Power-heuristic weight (N,) of strategy a against b, one sample each."""
    return power_heuristic(torch.stack([pdf_a, pdf_b], -1))[..., 0]


def _lum(c: torch.Tensor) -> torch.Tensor:
    return 0.2126 * c[..., 0] + 0.7152 * c[..., 1] + 0.0722 * c[..., 2]


def specular_probability(n_dot_v: torch.Tensor, albedo: torch.Tensor, metallic: torch.Tensor
                         ) -> torch.Tensor:
    """Probability (N,) of drawing a GGX sample rather than a cosine sample.

    Proportional to the luminance of the Fresnel reflectance at n·v against that of the diffuse
    weight (1 − m)·albedo, at least :data:`MIN_SPEC_PROB`; exactly 1 for pure metals.
    """
    f = fresnel_schlick(f0_from(albedo, metallic), n_dot_v[:, None].clamp(0, 1))
    w_s = _lum(f)
    w_d = _lum((1 - metallic) * albedo)
    p = w_s / (w_s + w_d).clamp_min(1e-8)
    return torch.where(w_d > 0, p.clamp(MIN_SPEC_PROB, 1.0), torch.ones_like(p))


def bsdf_pdf(n: torch.Tensor, v: torch.Tensor, l: torch.Tensor, alpha: torch.Tensor,
             p_spec: torch.Tensor) -> torch.Tensor:
    """Solid-angle pdf (N,) of the cosine/GGX-VNDF mixture for directions ``l`` (N, 3)."""
    return (1 - p_spec) * pdf_cosine(n, l) + p_spec * pdf_ggx_vndf(n, v, l, alpha)


def trace_paths(geometry: Union, materials: MaterialTable, env, o: torch.Tensor,
                d: torch.Tensor, max_depth: int = 3,
                generator: torch.Generator | None = None, brdf: Callable = brdf_eval
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Radiance arriving at ray origins from direction −d, by path tracing.

    Args:
        geometry: the scene's shapes (:class:`voxnero.synth.shapes.Union`).
        materials: one material per shape, in the same order.
        env: a :class:`voxnero.render.envmap.EnvMap` (``lookup``, ``sample``, ``pdf``).
        o: (N, 3) ray origins (world).
        d: (N, 3) unit ray directions (world).
        max_depth: number of surface interactions (≥ 1).
        generator: random generator (CPU) for reproducible noise.
        brdf: the BRDF, signature of :func:`voxnero.render.brdf.brdf_eval` (the default; tests
            pass a pure Lambertian one for the white furnace). Sampling stays the cosine/GGX
            mixture, so any BRDF is estimated without bias.

    Returns:
        (N, 3) linear radiance, and the primary intersection: t (N,) (``inf`` on a miss) and
        object index (N,) (−1 on a miss), for the ground-truth maps.
    """
    dev, dt = o.device, o.dtype

    def rand(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=generator, dtype=dt).to(dev)

    n_rays = o.shape[0]
    L = torch.zeros(n_rays, 3, dtype=dt, device=dev)
    beta = torch.ones(n_rays, 3, dtype=dt, device=dev)
    idx = torch.arange(n_rays, device=dev)
    prev_pdf: torch.Tensor | None = None
    for depth in range(max_depth + 1):
        if idx.numel() == 0:
            break
        t, hit, obj = geometry.intersect(o, d)
        if depth == 0:
            first_t, first_obj = t, obj
        esc = ~hit
        if esc.any():
            le = env.lookup(d[esc])
            if prev_pdf is not None:  # escaped after a BRDF sample: MIS against env sampling
                le = le * _mis(prev_pdf[esc], env.pdf(d[esc]))[:, None]
            L.index_add_(0, idx[esc], beta[esc] * le)
        if depth == max_depth:
            break
        idx, t, obj, o, d, beta = idx[hit], t[hit], obj[hit], o[hit], d[hit], beta[hit]
        x = o + t[:, None] * d
        n = geometry.normal(x, obj)
        v = -d
        albedo, metallic, rough = materials.gather(obj)
        alpha = roughness_to_alpha(rough)
        n_dot_v = (n * v).sum(-1)
        p_spec = specular_probability(n_dot_v, albedo, metallic)
        x_off = x + RAY_EPS * n

        # next-event estimation: one env-map sample with an exact shadow ray
        l_e, pdf_e = env.sample(rand(idx.numel(), 2))
        cos_e = (n * l_e).sum(-1)
        ok = (cos_e > 0) & (pdf_e > 0)
        if ok.any():
            k = torch.nonzero(ok).squeeze(1)
            _, blocked, _ = geometry.intersect(x_off[k], l_e[k])
            k = k[~blocked]
            if k.numel():
                f = brdf(n[k], v[k], l_e[k], albedo[k], metallic[k], rough[k])
                w = _mis(pdf_e[k], bsdf_pdf(n[k], v[k], l_e[k], alpha[k], p_spec[k]))
                contrib = f * (cos_e[k] * w / pdf_e[k])[:, None] * env.lookup(l_e[k])
                L.index_add_(0, idx[k], beta[k] * contrib)

        # continue the path with a BRDF sample
        u_lobe, u = rand(idx.numel()), rand(idx.numel(), 2)
        l_c, _ = sample_cosine(u, n)
        l_s, _ = sample_ggx_vndf(u, n, v, alpha)
        l = torch.where((u_lobe < p_spec)[:, None], l_s, l_c)
        pdf = bsdf_pdf(n, v, l, alpha, p_spec)
        cos_l = (n * l).sum(-1)
        ok = (cos_l > 0) & (pdf > 0) & (n_dot_v > 0)
        f = brdf(n, v, l, albedo, metallic, rough)
        beta = beta * f * (cos_l / pdf.clamp_min(1e-30))[:, None]
        ok &= torch.isfinite(beta).all(-1) & (beta.amax(-1) > 0)
        idx, beta, prev_pdf = idx[ok], beta[ok], pdf[ok]
        o, d = x_off[ok], l[ok]
    return L, first_t, first_obj


