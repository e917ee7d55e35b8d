"""Microfacet terms of the one BRDF: GGX D, Smith masking, Schlick Fresnel, F0, alpha.

The layer under everything that shades (``brdf.py``, ``sampling.py``, ``splitsum.py``,
``envmap.py``): pure functions that import nothing from the rest of the package, so that the
split-sum table (built by sampling these terms) and the BRDF (which needs that table for its
diffuse energy weight) both sit above it without an import cycle. A new lobe, Fresnel or
masking variant is written here and added to ``brdf.brdf_eval`` (see ``brdf.py`` for the
conventions and the numerics: alpha = r^2 clamped at ``ALPHA_MIN``, the bounded visibility form,
D from sin^2 theta_h).
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

#: Smallest perceptual roughness the clamp leaves alone: sqrt(ALPHA_MIN) = 0.0316. A learnable
#: roughness kept at or above it (:func:`roughness_from_raw`) never enters the clamped range,
#: where every value renders the same mirror with a zero gradient and a parameter that slid
#: there could never come back (stage 2's dielectrics did: docs/STAGE2.md, "Roughness near a
#: mirror").
ROUGHNESS_MIN: float = math.sqrt(ALPHA_MIN)

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


def roughness_from_raw(raw: Tensor, r_min: float = ROUGHNESS_MIN) -> Tensor:
    """Perceptual roughness of a learnable raw value: ``r_min + (1 - r_min) sigmoid(raw)``.

    Args:
        raw: any shape, unbounded.
        r_min: the smallest roughness (at ``ROUGHNESS_MIN`` or above, the gradient never
            vanishes at the alpha clamp).

    Returns:
        roughness in (r_min, 1), same shape.
    """
    return r_min + (1.0 - r_min) * torch.sigmoid(raw)


def raw_from_roughness(r: float, r_min: float = ROUGHNESS_MIN) -> float:
    """Inverse of :func:`roughness_from_raw` (``r`` taken into [r_min, 1], the logit's argument
    into [1e-4, 1 - 1e-4] so that it stays finite)."""
    p = (min(max(r, r_min), 1.0) - r_min) / (1.0 - r_min)
    p = min(max(p, 1e-4), 1 - 1e-4)
    return math.log(p / (1 - p))


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
