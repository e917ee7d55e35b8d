"""Monte Carlo rendering equation on fixed surface points (stage 2).

For a surface point x with shading normal n, seen from the unit direction v::

    L_o(x, v) = ∫ f_r(n, v, l) L_i(x, l) max(n·l, 0) dl

is estimated with three sampling strategies of the shading core — cosine-weighted
(``sample_cosine``), GGX visible normals (``sample_ggx_vndf``) and the env map's own importance
sampling (``voxnero.render.envmap.EnvMap.sample``) — combined by multiple
importance sampling with the power heuristic (multi-sample MIS, Veach 1997)::

    F = Σ_k (1 / n_k) Σ_j w_k(l_kj) f L_i cos / p_k(l_kj),
    w_k = (n_k p_k)² / Σ_i (n_i p_i)²,   so   w_k / (n_k p_k) = n_k p_k / Σ_i (n_i p_i)².

Samples are a fixed 2-D Hammersley pattern per strategy shifted by a random toroidal offset
per pixel (Cranley–Patterson rotation): stratified, low-variance and unbiased. Sampling uses
the material *detached* (so the pdfs are constants and the gradient of the estimate is an
unbiased estimate of the gradient of L_o). L_i is the env map along l if the secondary ray
leaves the object (Open3D ``test_occlusions``), else the indirect estimate at the first hit
(:class:`voxnero.material.lights.IndirectLight`), or 0 when indirect light is off.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from voxnero.material.lights import IndirectLight
from voxnero.material.surface import Geometry
from voxnero.render.brdf import brdf_eval, roughness_to_alpha
from voxnero.render.envmap import EnvMap
from voxnero.render.sampling import pdf_cosine, pdf_ggx_vndf, sample_cosine, sample_ggx_vndf
from voxnero.render.splitsum import hammersley


@dataclass
class Strategies:
    """Samples per pixel of each strategy."""

    cos: int = 8
    ggx: int = 8
    env: int = 8

    @property
    def total(self) -> int:
        return self.cos + self.ggx + self.env


def env_sampler(image: Tensor) -> EnvMap:
    """The shading core's env-map importance sampler for a (detached) map.

    Args:
        image: (H, W, 3) linear map.

    Returns:
        An :class:`voxnero.render.envmap.EnvMap`: ``sample(u (N, 2)) -> (dirs (N, 3), pdf (N,))``
        and ``pdf(d) -> (N,)``.
    """
    return EnvMap(image.detach())


def rotated_pattern(n_pix: int, n: int, generator: torch.Generator | None,
                    device: torch.device | str = "cpu") -> Tensor:
    """Hammersley pattern of n points, randomly shifted (mod 1) per pixel: (n_pix, n, 2)."""
    base = hammersley(n, dtype=torch.float32).to(device) if n > 1 else \
        torch.full((1, 2), 0.5, device=device)
    # drawn with the (CPU) generator, then moved: the same stream on every device
    shift = torch.rand((n_pix, 1, 2), generator=generator).to(device)
    return torch.remainder(base[None] + shift, 1.0).clamp(0.0, 1.0 - 1e-7)


def sample_directions(n: Tensor, v: Tensor, alpha: Tensor, spp: Strategies, env=None,
                      generator: torch.Generator | None = None,
                      patterns: list[Tensor | None] | None = None
                      ) -> tuple[Tensor, Tensor, list[int]]:
    """Draw all strategies' directions and the MIS weight-over-pdf of each.

    Args:
        n: (N, 3) unit normals; v: (N, 3) unit view directions; alpha: (N, 1) GGX alpha
            (detached).
        spp: samples per strategy (the env strategy is dropped when ``env`` is None).
        env: env-map sampler (see :func:`env_sampler`) or None.
        generator: random stream.
        patterns: optional uniform points per strategy (cosine, GGX, env), each (N, count, 2)
            or None, used instead of a fresh :func:`rotated_pattern` (e.g. one pixel's pattern
            shared out among its subpixels).

    Returns:
        l (N, S, 3) unit directions, wop (N, S) = w_k / (n_k p_k) of the strategy that drew each
        sample, and the counts [n_cos, n_ggx, n_env] actually used.
    """
    N = n.shape[0]
    counts = [spp.cos, spp.ggx, spp.env if env is not None else 0]
    dirs, owner = [], []
    for k, c in enumerate(counts):
        if c == 0:
            continue
        u = patterns[k] if patterns is not None and patterns[k] is not None else \
            rotated_pattern(N, c, generator, n.device)
        u = u.to(n.device).reshape(-1, 2)
        nk = n[:, None].expand(N, c, 3).reshape(-1, 3)
        if k == 0:
            l, _ = sample_cosine(u, nk)
        elif k == 1:
            vk = v[:, None].expand(N, c, 3).reshape(-1, 3)
            ak = alpha[:, None].expand(N, c, 1).reshape(-1)
            l, _ = sample_ggx_vndf(u, nk, vk, ak)
        else:
            l, _ = env.sample(u)
            l = l.to(n.dtype)
        dirs.append(l.view(N, c, 3))
        owner += [k] * c
    l = torch.cat(dirs, 1)
    S = l.shape[1]
    nS = n[:, None].expand(N, S, 3).reshape(-1, 3)
    lS = l.reshape(-1, 3)
    q = []
    if counts[0]:
        q.append(counts[0] * pdf_cosine(nS, lS))
    else:
        q.append(torch.zeros(N * S, device=n.device))
    if counts[1]:
        vS = v[:, None].expand(N, S, 3).reshape(-1, 3)
        aS = alpha[:, None].expand(N, S, 1).reshape(-1)
        q.append(counts[1] * pdf_ggx_vndf(nS, vS, lS, aS))
    else:
        q.append(torch.zeros(N * S, device=n.device))
    if counts[2]:
        q.append(counts[2] * env.pdf(lS).to(n.dtype).reshape(-1))
    else:
        q.append(torch.zeros(N * S, device=n.device))
    q = torch.stack(q, -1).view(N, S, 3)
    own = torch.tensor(owner, device=n.device)
    q_own = q.gather(-1, own.view(1, S, 1).expand(N, S, 1))[..., 0]
    denom = (q * q).sum(-1)
    wop = torch.where(denom > 0, q_own / denom.clamp_min(1e-30), torch.zeros_like(denom))
    return l, wop, counts


def incident_radiance(geom: Geometry, field, env_image: Tensor, indirect: IndirectLight | None,
                      tri: Tensor, x: Tensor, l: Tensor, visibility: bool = True) -> Tensor:
    """L_i along secondary rays: env map if the ray escapes, indirect estimate if it hits.

    Args:
        geom: the mesh; field: material field; env_image: (H, W, 3) current linear map.
        indirect: indirect-light model, or None (occluded rays carry 0).
        tri: (N,) triangles of the surface points; x: (N, 3) points; l: (N, S, 3) directions.
        visibility: if False, every ray sees the env map (no shadows).

    Returns:
        (N, S, 3) linear radiance.
    """
    from voxnero.render.envmap import envmap_lookup

    N, S = l.shape[:2]
    Li = envmap_lookup(env_image, l)
    if not visibility:
        return Li
    o = geom.spawn(tri[:, None].expand(N, S), x[:, None].expand(N, S, 3), l)
    o, lf = o.reshape(-1, 3), l.reshape(-1, 3)
    occ = geom.occluded(o, lf).to(l.device)
    if not occ.any():
        return Li
    Li = Li.reshape(-1, 3)
    if indirect is None:
        Li = torch.where(occ[:, None], torch.zeros_like(Li), Li)
        return Li.view(N, S, 3)
    idx = occ.nonzero()[:, 0]
    _, htri, hbary = geom.cast(o[idx], lf[idx])
    ok = htri >= 0
    idx, htri, hbary = idx[ok], htri[ok].to(l.device), hbary[ok].to(l.device)
    hx = geom.points_at(htri, hbary)
    hn = geom.normals_at(htri, hbary)
    a, m, r = field(htri, hbary, hx)
    Lind = indirect.radiance(hn, -lf[idx], a, m, r)
    Li = Li.clone()
    Li[occ] = 0.0
    Li = Li.index_put((idx,), Lind)
    return Li.view(N, S, 3)


def shade(geom: Geometry, field, env_image: Tensor, tri: Tensor, bary: Tensor, x: Tensor,
          n: Tensor, v: Tensor, spp: Strategies, indirect: IndirectLight | None = None,
          env=None, visibility: bool = True, generator: torch.Generator | None = None,
          patterns: list[Tensor | None] | None = None) -> Tensor:
    """Outgoing radiance L_o(x, v) of surface points, Monte Carlo with MIS (see module).

    Args:
        geom: the mesh (unit frame); field: material field ``(tri, bary, x) -> (albedo (N, 3),
            metallic (N, 1), roughness (N, 1))``.
        env_image: (H, W, 3) linear env map (differentiable).
        tri: (N,) triangles; bary: (N, 3) barycentrics; x: (N, 3) points; n: (N, 3) unit
            shading normals; v: (N, 3) unit directions toward the viewer.
        spp: samples per strategy.
        indirect: indirect light model or None (occluded secondary rays carry 0).
        env: env-map sampler for the env strategy (:func:`env_sampler`) or None.
        visibility: cast secondary rays (shadows / indirect); False treats all as escaping.
        generator: random stream.
        patterns: see :func:`sample_directions`.

    Returns:
        (N, 3) linear radiance.
    """
    albedo, metallic, roughness = field(tri, bary, x)
    alpha = roughness_to_alpha(roughness.detach())
    l, wop, _ = sample_directions(n, v, alpha, spp, env, generator, patterns)
    S = l.shape[1]
    nS = n[:, None].expand_as(l)
    f = brdf_eval(nS, v[:, None].expand_as(l), l, albedo[:, None].expand(-1, S, 3),
                  metallic[:, None].expand(-1, S, 1), roughness[:, None].expand(-1, S, 1))
    cos = (nS * l).sum(-1).clamp_min(0.0)
    Li = incident_radiance(geom, field, env_image, indirect, tri, x, l, visibility)
    return (f * Li * (cos * wop)[..., None]).sum(1)
