"""Importance samplers for the rendering equation and multiple-importance-sampling weights.

All pdfs are per steradian of the sampled direction l. Directions point away from the surface.
Samplers take uniform numbers ``u (N, 2)`` in [0, 1)^2 so that callers control the random
stream (a ``torch.Generator``, stratified or quasi-random points).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from voxnero.render.microfacet import ALPHA_MIN, ggx_D, safe_normalize

#: Smallest n.v used to sample the visible normals: views at or below the horizon are treated
#: as grazing (the BRDF is 0 there anyway, but samples and pdfs stay finite).
NV_MIN = 1e-4


def frame_from_normal(n: Tensor) -> tuple[Tensor, Tensor]:
    """Orthonormal tangent frame (t, b, n) for any normal (Duff et al. 2017, branchless).

    Args:
        n: (..., 3) unit normals (zero-length input gives +Z's frame).

    Returns:
        t, b: (..., 3) unit tangents with t x b = n.
    """
    n = safe_normalize(n)
    zero = (n * n).sum(-1) < 0.5
    n = torch.where(zero[..., None], torch.tensor([0.0, 0.0, 1.0], dtype=n.dtype,
                                                  device=n.device), n)
    x, y, z = n.unbind(-1)
    sign = torch.where(z >= 0, torch.ones_like(z), -torch.ones_like(z))
    a = -1.0 / (sign + z)
    b_ = x * y * a
    t = torch.stack([1.0 + sign * x * x * a, sign * b_, -sign * x], dim=-1)
    b = torch.stack([b_, sign + y * y * a, -y], dim=-1)
    return t, b


def _to_local(d: Tensor, t: Tensor, b: Tensor, n: Tensor) -> Tensor:
    return torch.stack([(d * t).sum(-1), (d * b).sum(-1), (d * n).sum(-1)], dim=-1)


def _to_world(d: Tensor, t: Tensor, b: Tensor, n: Tensor) -> Tensor:
    return d[..., 0:1] * t + d[..., 1:2] * b + d[..., 2:3] * n


def sample_cosine(u: Tensor, n: Tensor) -> tuple[Tensor, Tensor]:
    """Cosine-weighted hemisphere samples around n (Malley's method).

    Args:
        u: (N, 2) uniforms in [0, 1).
        n: (N, 3) unit normals (broadcastable).

    Returns:
        l: (N, 3) unit directions; pdf: (N,) = max(n.l, 0) / pi per steradian.
    """
    n = safe_normalize(n)
    r = torch.sqrt(u[..., 0].clamp(0.0, 1.0))
    phi = 2.0 * math.pi * u[..., 1]
    x, y = r * torch.cos(phi), r * torch.sin(phi)
    z = torch.sqrt((1.0 - x * x - y * y).clamp_min(0.0))
    t, b = frame_from_normal(n)
    l = safe_normalize(_to_world(torch.stack([x, y, z], -1), t, b, n))
    return l, pdf_cosine(n, l)


def pdf_cosine(n: Tensor, l: Tensor) -> Tensor:
    """Pdf of ``sample_cosine``: max(n.l, 0) / pi. Shapes (..., 3) -> (...,)."""
    return (safe_normalize(n) * l).sum(-1).clamp_min(0.0) / math.pi


def _local_view(n: Tensor, v: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    n = safe_normalize(n)
    t, b = frame_from_normal(n)
    vl = _to_local(safe_normalize(v), t, b, n)
    # views at/below the horizon: lift to n.v = NV_MIN (keeps the azimuth)
    vz = vl[..., 2].clamp_min(NV_MIN)
    rxy = torch.sqrt((vl[..., 0] ** 2 + vl[..., 1] ** 2).clamp_min(1e-30))
    sxy = torch.sqrt((1.0 - vz * vz).clamp_min(0.0)) / rxy
    lifted = torch.stack([vl[..., 0] * sxy, vl[..., 1] * sxy, vz], -1)
    vl = torch.where((vl[..., 2] < NV_MIN)[..., None], lifted, vl)
    return vl, t, b, n


def sample_ggx_vndf(u: Tensor, n: Tensor, v: Tensor,
                    alpha: Tensor | float) -> tuple[Tensor, Tensor]:
    """Sample l = reflect(v, h) with h from GGX's distribution of visible normals (Heitz 2018).

    The pdf of l is D_v(h) / (4 v.h) with D_v(h) = G1(v) max(v.h, 0) D(h) / (n.v), i.e.
    pdf(l) = G1(v) D(h) / (4 n.v) = D(h) / (2 (n.v + sqrt(alpha^2 + (1 - alpha^2)(n.v)^2))).
    Returned directions may lie below the surface (n.l < 0; their BRDF is 0).

    Args:
        u: (N, 2) uniforms in [0, 1).
        n: (N, 3) unit normals.
        v: (N, 3) unit view directions (away from the surface); n.v <= 0 is lifted to NV_MIN.
        alpha: GGX alpha, float or (N,) / (N, 1); clamped to [ALPHA_MIN, 1].

    Returns:
        l: (N, 3) unit directions; pdf: (N,) per steradian of l.
    """
    a = torch.as_tensor(alpha, dtype=n.dtype, device=n.device).clamp(ALPHA_MIN, 1.0)
    if a.dim() > 0 and a.shape[-1] == 1 and a.dim() == n.dim():
        a = a[..., 0]
    vl, t, b, n = _local_view(n, v)
    ll = sample_vndf_local(u, vl, a)
    l = safe_normalize(_to_world(ll, t, b, n))
    pdf = _vndf_pdf_local(vl, ll, a)
    return l, pdf


def sample_vndf_local(u: Tensor, vl: Tensor, a: Tensor) -> Tensor:
    """Heitz 2018 VNDF sampling in the local frame (normal = +Z); returns l = reflect(v, h).

    Args:
        u: (N, 2) uniforms.
        vl: (N, 3) unit view directions in the local frame with vl_z > 0.
        a: (N,) or scalar GGX alpha (already clamped).

    Returns:
        (N, 3) local reflected directions (not normalised beyond float rounding).
    """
    vh = safe_normalize(torch.stack([a * vl[..., 0], a * vl[..., 1], vl[..., 2]], -1))
    lensq = vh[..., 0] ** 2 + vh[..., 1] ** 2
    inv = torch.rsqrt(lensq.clamp_min(1e-30))
    has = lensq > 1e-14
    zero = torch.zeros_like(lensq)
    t1 = torch.stack([torch.where(has, -vh[..., 1] * inv, zero + 1.0),
                      torch.where(has, vh[..., 0] * inv, zero), zero], -1)
    t2 = torch.linalg.cross(vh, t1)
    r = torch.sqrt(u[..., 0].clamp(0.0, 1.0))
    phi = 2.0 * math.pi * u[..., 1]
    p1 = r * torch.cos(phi)
    p2 = r * torch.sin(phi)
    s = 0.5 * (1.0 + vh[..., 2])
    p2 = (1.0 - s) * torch.sqrt((1.0 - p1 * p1).clamp_min(0.0)) + s * p2
    pz = torch.sqrt((1.0 - p1 * p1 - p2 * p2).clamp_min(0.0))
    nh = p1[..., None] * t1 + p2[..., None] * t2 + pz[..., None] * vh
    hl = safe_normalize(torch.stack([a * nh[..., 0], a * nh[..., 1],
                                     nh[..., 2].clamp_min(0.0)], -1))
    vdh = (vl * hl).sum(-1, keepdim=True)
    return 2.0 * vdh * hl - vl


def _vndf_pdf_local(vl: Tensor, ll: Tensor, a: Tensor) -> Tensor:
    h = safe_normalize(vl + ll)
    vdh = (vl * h).sum(-1)
    nv = vl[..., 2]
    a2 = a * a
    s = torch.sqrt(a2 + (1.0 - a2) * nv * nv)
    pdf = ggx_D(h[..., 2], a, h[..., 0] ** 2 + h[..., 1] ** 2) / (2.0 * (nv + s))
    return torch.where((vdh > 0) & (h[..., 2] > 0), pdf, torch.zeros_like(pdf))


def pdf_ggx_vndf(n: Tensor, v: Tensor, l: Tensor, alpha: Tensor | float) -> Tensor:
    """Pdf per steradian of ``sample_ggx_vndf`` for the direction l.

    Args:
        n, v, l: (N, 3) unit vectors.
        alpha: GGX alpha, float or (N,) / (N, 1).

    Returns:
        (N,) pdf; 0 where the half vector faces away from v or n.
    """
    a = torch.as_tensor(alpha, dtype=n.dtype, device=n.device).clamp(ALPHA_MIN, 1.0)
    if a.dim() > 0 and a.shape[-1] == 1 and a.dim() == n.dim():
        a = a[..., 0]
    vl, t, b, n = _local_view(n, v)
    ll = _to_local(safe_normalize(l), t, b, n)
    return _vndf_pdf_local(vl, ll, a)


def power_heuristic(pdfs: Tensor, counts: Tensor | list[int] | None = None,
                    beta: float = 2.0) -> Tensor:
    """Multiple-importance-sampling weights of K strategies (Veach's power heuristic).

    w_k = (n_k p_k)^beta / sum_j (n_j p_j)^beta, computed after dividing by the largest term
    (no overflow for pdfs up to float max). Where all pdfs are 0 the weights are 1/K.

    Args:
        pdfs: (..., K) the pdf of every strategy at the same direction.
        counts: (K,) number of samples drawn by each strategy (default 1 each).
        beta: exponent (2 = power heuristic, 1 = balance heuristic).

    Returns:
        (..., K) weights summing to 1 over K.
    """
    q = pdfs.clamp_min(0.0)
    if counts is not None:
        q = q * torch.as_tensor(counts, dtype=q.dtype, device=q.device)
    m = q.amax(-1, keepdim=True)
    ok = m > 0
    q = torch.where(ok, q / torch.where(ok, m, torch.ones_like(m)), torch.ones_like(q))
    q = q**beta
    return q / q.sum(-1, keepdim=True)


def balance_heuristic(pdfs: Tensor, counts: Tensor | list[int] | None = None) -> Tensor:
    """Balance-heuristic MIS weights w_k = n_k p_k / sum_j n_j p_j; see ``power_heuristic``."""
    return power_heuristic(pdfs, counts, beta=1.0)
