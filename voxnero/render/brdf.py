"""Microfacet BRDF: GGX normal distribution, Smith masking, Schlick Fresnel, Lambert diffuse.

The one BRDF of the project (both stages render with it)::

    f_r(v, l) = (1 - m) * albedo / pi  +  D(h) * G(v, l) * F(v.h) / (4 (n.v) (n.l))

with F0 = 0.04 (1 - m) + m * albedo, alpha = roughness^2 (perceptual roughness r in [0, 1],
clamped below at ``ALPHA_MIN``), D = GGX / Trowbridge-Reitz, G = **separable** Smith
G1(v) * G1(l) for GGX (the form Mitsuba's ``principled`` BSDF uses, which rendered the dev
scenes; ``smith_G_height_correlated`` is available for comparison) and Schlick's Fresnel.

Numerics: every function is finite, with finite gradients, for any input, including
zero-length or non-unit vectors, n.v <= 0, roughness exactly 0 or 1. The specular term is
computed through the "visibility" form G / (4 n.v n.l) = 1 / ((n.v + s_v)(n.l + s_l)) with
s_x = sqrt(alpha^2 + (1 - alpha^2)(n.x)^2), which is bounded by 1 / alpha^2 even at grazing
angles. D is evaluated from sin^2(theta_h) = |n x h|^2 rather than 1 - (n.h)^2: near the lobe
centre of a mirror (alpha = 1e-3, alpha^2 = 1e-6) float32 rounding of n.h alone moved D by ~10 %
and a mirror under a white furnace returned 1.04 instead of 1.

Energy: the diffuse lobe is weighted by (1 - E_d(v))(1 - E_d(l)) / (1 - E_avg), where
E_d = 0.04 A + B is the directional albedo of the dielectric specular lobe (split-sum table,
``splitsum.py``) and E_avg its cosine average: light the dielectric interface reflects does
not also enter the diffuse layer, and the weight is symmetric in v and l (reciprocity). With
albedo 1 the surface then returns exactly what it receives at every roughness, metalness and
angle (a white furnace gives 1, up to the table's 1e-3), and never more. Mitsuba's
``principled`` (the dev data) and NeRO do not weight the diffuse lobe; their dielectrics
reflect up to 1.95x at grazing angles, and our dielectric renders are ~5 % darker than theirs.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

#: Smallest GGX alpha (= roughness^2). D(n.h = 1) = 1 / (pi alpha^2) = 3.2e5 and its derivative
#: stay finite in float32 (dD/d(n.h) <= ~4 / (pi alpha^2) per unit n.h); the lobe is 0.06 deg
#: wide, far below an env-map pixel (0.7 deg at 512 x 256), so it renders a mirror.
#: Perceptual roughness below sqrt(ALPHA_MIN) = 0.0316 maps to ALPHA_MIN (zero gradient there).
ALPHA_MIN: float = 1e-3

#: Normal-incidence reflectance of the dielectric part (index of refraction 1.5).
DIELECTRIC_F0: float = 0.04

_EPS = 1e-12


def safe_normalize(x: Tensor, eps: float = 1e-12) -> Tensor:
    """Normalise vectors along the last axis; zero-length vectors map to zero (finite grads).

    Args:
        x: (..., 3) vectors.
        eps: squared-length floor.

    Returns:
        (..., 3) unit vectors (or zeros where |x| = 0).
    """
    sq = (x * x).sum(-1, keepdim=True)
    return x * torch.rsqrt(sq.clamp_min(eps))


def dot(a: Tensor, b: Tensor) -> Tensor:
    """Dot product over the last axis, keeping it: (..., 3), (..., 3) -> (..., 1)."""
    return (a * b).sum(-1, keepdim=True)


def roughness_to_alpha(r: Tensor | float) -> Tensor:
    """GGX alpha from perceptual roughness: clamp(r, 0, 1)^2, clamped below at ``ALPHA_MIN``.

    Args:
        r: perceptual roughness, any shape.

    Returns:
        alpha, same shape (a tensor).
    """
    r = torch.as_tensor(r)
    return (r.clamp(0.0, 1.0) ** 2).clamp_min(ALPHA_MIN)


def _alpha(alpha: Tensor | float) -> Tensor:
    return torch.as_tensor(alpha).clamp(ALPHA_MIN, 1.0)


def ggx_D(n_dot_h: Tensor, alpha: Tensor | float, sin2_h: Tensor | None = None) -> Tensor:
    """GGX (Trowbridge-Reitz) normal distribution D(h), per steradian of half vectors.

    D = alpha^2 / (pi (alpha^2 c^2 + s^2)^2) with c = n.h clamped to [0, 1] and s^2 = 1 - c^2;
    normalised so that the integral of D(h) (n.h) over the hemisphere is 1. Values for
    n.h <= 0 are those of c = 0 (callers mask the lower hemisphere).

    Args:
        n_dot_h: cosine between normal and half vector, any shape.
        alpha: GGX alpha (= roughness^2), broadcastable; clamped to [ALPHA_MIN, 1].
        sin2_h: optional sin^2 of the same angle computed without cancellation (|n x h|^2, or
            h_x^2 + h_y^2 in a local frame); strongly recommended for small alpha, where
            1 - c^2 from a float32 cosine is off by ~1e-7 against alpha^2 = 1e-6.

    Returns:
        D, broadcast shape; at most 1 / (pi alpha^2).
    """
    a2 = _alpha(alpha) ** 2
    c = n_dot_h.clamp(0.0, 1.0)
    sin2 = (1.0 - c) * (1.0 + c)  # 1 - c^2 without cancellation near c = 1
    if sin2_h is not None:  # use it where the vectors were unit (c^2 + s^2 = 1 to 1e-3)
        s2 = sin2_h.clamp(0.0, 1.0)
        ok = (n_dot_h > 0) & ((c * c + s2 - 1.0).abs() < 1e-3)
        sin2 = torch.where(ok, s2, sin2)
    denom = a2 * c * c + sin2
    return a2 / (math.pi * denom * denom)


def _smith_s(n_dot_x: Tensor, a2: Tensor) -> Tensor:
    """sqrt(alpha^2 + (1 - alpha^2) c^2) with c = clamp(n.x, 0, 1); >= alpha > 0."""
    c = n_dot_x.clamp(0.0, 1.0)
    return torch.sqrt(a2 + (1.0 - a2) * c * c)


def smith_G1(n_dot_x: Tensor, alpha: Tensor | float) -> Tensor:
    """Smith masking G1 for GGX: 2 c / (c + sqrt(alpha^2 + (1 - alpha^2) c^2)), c = n.x.

    Exact for GGX (not the Schlick approximation); 0 for n.x <= 0.

    Args:
        n_dot_x: cosine between normal and the direction, any shape.
        alpha: GGX alpha, broadcastable; clamped to [ALPHA_MIN, 1].

    Returns:
        G1 in [0, 1], broadcast shape.
    """
    a2 = _alpha(alpha) ** 2
    c = n_dot_x.clamp(0.0, 1.0)
    return 2.0 * c / (c + _smith_s(n_dot_x, a2))


def smith_G(n_dot_v: Tensor, n_dot_l: Tensor, alpha: Tensor | float) -> Tensor:
    """Separable Smith shadowing-masking G = G1(v) G1(l) (the default used by ``brdf_eval``).

    Args:
        n_dot_v: cosine to the view direction, any shape.
        n_dot_l: cosine to the light direction, broadcastable.
        alpha: GGX alpha, broadcastable.

    Returns:
        G in [0, 1], broadcast shape.
    """
    return smith_G1(n_dot_v, alpha) * smith_G1(n_dot_l, alpha)


def smith_G_height_correlated(n_dot_v: Tensor, n_dot_l: Tensor, alpha: Tensor | float) -> Tensor:
    """Height-correlated Smith G2 = 1 / (1 + Lambda(v) + Lambda(l)) for GGX (not the default).

    Args:
        n_dot_v: cosine to the view direction, any shape.
        n_dot_l: cosine to the light direction, broadcastable.
        alpha: GGX alpha, broadcastable.

    Returns:
        G2 in [0, 1], broadcast shape; 0 where either cosine is <= 0.
    """
    a2 = _alpha(alpha) ** 2
    cv = n_dot_v.clamp(0.0, 1.0)
    cl = n_dot_l.clamp(0.0, 1.0)
    # 2 c Lambda(c) = s - c  =>  G2 = 2 cv cl / (cl (s_v - cv) + cv (s_l - cl) + 2 cv cl)
    sv = _smith_s(n_dot_v, a2)
    sl = _smith_s(n_dot_l, a2)
    num = 2.0 * cv * cl
    den = cl * sv + cv * sl
    return num / den.clamp_min(_EPS)


def schlick_ggx_G(n_dot_v: Tensor, n_dot_l: Tensor, alpha: Tensor | float) -> Tensor:
    """Schlick-GGX G with NeRO's k = alpha / 2 (an approximation; not the default).

    G = c_v / (c_v (1 - k) + k) * c_l / (c_l (1 - k) + k).

    Args:
        n_dot_v: cosine to the view direction, any shape.
        n_dot_l: cosine to the light direction, broadcastable.
        alpha: GGX alpha, broadcastable.

    Returns:
        G in [0, 1], broadcast shape.
    """
    k = _alpha(alpha) / 2.0
    cv = n_dot_v.clamp(0.0, 1.0)
    cl = n_dot_l.clamp(0.0, 1.0)
    return cv / (cv * (1.0 - k) + k) * cl / (cl * (1.0 - k) + k)


def fresnel_schlick(f0: Tensor, cos_theta: Tensor) -> Tensor:
    """Schlick Fresnel F = F0 + (1 - F0)(1 - cos)^5, cos clamped to [0, 1].

    Args:
        f0: reflectance at normal incidence, e.g. (..., 3).
        cos_theta: cosine between the half vector and v (or l), e.g. (..., 1).

    Returns:
        F, broadcast shape, in [F0, 1].
    """
    c = cos_theta.clamp(0.0, 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


def f0_from(albedo: Tensor, metallic: Tensor) -> Tensor:
    """Normal-incidence reflectance F0 = 0.04 (1 - m) + m * albedo.

    Args:
        albedo: (..., 3) linear base colour.
        metallic: (..., 1) metalness in [0, 1].

    Returns:
        (..., 3) F0.
    """
    return DIELECTRIC_F0 * (1.0 - metallic) + metallic * albedo


def specular_visibility(n_dot_v: Tensor, n_dot_l: Tensor, alpha: Tensor | float) -> Tensor:
    """V = G / (4 n.v n.l) for separable Smith GGX, in the bounded form 1/((c_v+s_v)(c_l+s_l)).

    Finite for all inputs (<= 1 / alpha^2); callers mask n.v <= 0 or n.l <= 0.

    Args:
        n_dot_v: any shape.
        n_dot_l: broadcastable.
        alpha: GGX alpha, broadcastable.

    Returns:
        V, broadcast shape.
    """
    a2 = _alpha(alpha) ** 2
    cv = n_dot_v.clamp(0.0, 1.0)
    cl = n_dot_l.clamp(0.0, 1.0)
    return 1.0 / ((cv + _smith_s(n_dot_v, a2)) * (cl + _smith_s(n_dot_l, a2)))


def diffuse_weight(n_dot_v: Tensor, roughness: Tensor, n_dot_l: Tensor | None = None) -> Tensor:
    """Share of energy left for the diffuse lobe under the dielectric specular interface.

    With E_d(mu, r) = 0.04 A + B the directional albedo of the dielectric (F0 = 0.04) specular
    lobe (split-sum table) and E_avg its cosine-weighted average:

    * with ``n_dot_l`` (a BRDF value, reciprocal):  (1 - E_d(v)) (1 - E_d(l)) / (1 - E_avg),
      whose cosine integral over l is exactly 1 - E_d(v);
    * without it (split-sum shading, light integrated separately):  1 - E_d(v).

    So an albedo-1 dielectric returns what it receives (white furnace = 1) in both stages.

    Args:
        n_dot_v: (..., 1) cosine to the view direction.
        roughness: (..., 1) perceptual roughness.
        n_dot_l: optional (..., 1) cosine to the light direction.

    Returns:
        (..., 1) weight in [0, 1 / (1 - E_avg)].
    """
    from voxnero.render.splitsum import dielectric_albedo, dielectric_albedo_avg  # (cycle)

    w = 1.0 - dielectric_albedo(n_dot_v, roughness)
    if n_dot_l is None:
        return w
    return w * (1.0 - dielectric_albedo(n_dot_l, roughness)) / (
        1.0 - dielectric_albedo_avg(roughness))


def brdf_eval(
    n: Tensor, v: Tensor, l: Tensor, albedo: Tensor, metallic: Tensor, roughness: Tensor
) -> Tensor:
    """BRDF value f_r (per steradian, without the n.l cosine).

    f_r = (1 - m) W(v, l) albedo / pi + D G F / (4 n.v n.l), zero unless n.v > 0 and n.l > 0,
    with the reciprocal energy weight W = ``diffuse_weight(n.v, r, n.l)``.
    Direction inputs are re-normalised (zero-length vectors give 0), so slightly non-unit
    inputs are fine.

    Args:
        n: (..., 3) unit surface normal.
        v: (..., 3) unit direction toward the viewer (away from the surface).
        l: (..., 3) unit direction toward the light (away from the surface).
        albedo: (..., 3) linear base colour.
        metallic: (..., 1) metalness in [0, 1].
        roughness: (..., 1) perceptual roughness r (alpha = r^2, clamped at ALPHA_MIN).

    Returns:
        (..., 3) f_r, linear, 1/sr.
    """
    n = safe_normalize(n)
    v = safe_normalize(v)
    l = safe_normalize(l)
    h = safe_normalize(v + l)
    metallic = metallic.clamp(0.0, 1.0)
    alpha = roughness_to_alpha(roughness)
    nv, nl, nh, vh = dot(n, v), dot(n, l), dot(n, h), dot(v, h)
    sin2_h = dot(torch.linalg.cross(n, h, dim=-1), torch.linalg.cross(n, h, dim=-1))
    spec = ggx_D(nh, alpha, sin2_h) * specular_visibility(nv, nl, alpha)
    spec = spec * fresnel_schlick(f0_from(albedo, metallic), vh)
    diffuse = (1.0 - metallic) * diffuse_weight(nv, roughness, nl) * albedo / math.pi
    upper = (nv > 0) & (nl > 0)
    return torch.where(upper, diffuse + spec, torch.zeros_like(spec))
