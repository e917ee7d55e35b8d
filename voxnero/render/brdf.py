"""The one BRDF of the project (both stages and the ground-truth path tracer render with it)::

    f_r(v, l) = (1 - m) * albedo / pi * W  +  D(h) * G(v, l) * F(v.h) / (4 (n.v) (n.l))

with F0 = 0.04 (1 - m) + m * albedo, alpha = roughness^2 (perceptual roughness r in [0, 1],
clamped below at ``ALPHA_MIN``), D = GGX / Trowbridge-Reitz, G = **separable** Smith
G1(v) * G1(l) for GGX (the form Mitsuba's ``principled`` BSDF uses, which rendered the dev
scenes; ``smith_G_height_correlated`` is available for comparison) and Schlick's Fresnel. The
terms are in ``microfacet.py`` (the layer below ``sampling.py`` and ``splitsum.py``); this module
adds the energy-weighted diffuse lobe, which needs the split-sum table, and sums the lobes.

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

Diffuse lobe, two conventions (``DIFFUSE_MODELS``; ``W`` above):

* ``"weighted"`` (default; stage 1, the project's path tracer, glTF's ``fresnel_mix``): the
  energy weight above, ``W = diffuse_weight(n.v, r, n.l)``;
* ``"principled"``: the diffuse lobe of Mitsuba 3's ``principled`` BSDF (Burley 2015, the
  Disney BRDF fitted to measured materials; no retro-reflection split, flatness 0), which
  rendered the dev scenes and the corpus: with F_x = (1 - n.x)^5, cos_d = l.h and
  R_r = 2 r cos_d^2,

      W = (1 - F_l / 2)(1 - F_v / 2) + R_r (F_l + F_v + F_l F_v (R_r - 1)),

  not energy-weighted against the specular lobe (a dielectric of albedo 1 returns more than
  it receives at grazing angles). Rendering the true mesh, material and map of the corpus's
  oak table (roughness 0.55) through our estimator, the photos' object pixels are 1.08x the
  "weighted" render and 1.01x the "principled" one (34.6 against 32.1 dB; docs/STAGE2.md).
  Stage 2 fits with it by default (``material.render.diffuse``); stage 1 can shade with its
  closed-form directional albedo (:func:`principled_diffuse_albedo`, ``light.diffuse``, not
  its default: docs/STAGE1.md finding 27); the project's own path tracer (``voxnero synth``)
  keeps "weighted".
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from voxnero.render.microfacet import (
    dot,
    f0_from,
    fresnel_schlick,
    ggx_D,
    roughness_to_alpha,
    safe_normalize,
    specular_visibility,
)
from voxnero.render.splitsum import dielectric_albedo, dielectric_albedo_avg

DIFFUSE_MODELS = ("weighted", "principled")
"""The diffuse lobe's conventions (module docstring): energy-weighted Lambert, or the
``principled`` (Disney 2015) diffuse with retro-reflection."""


def check_diffuse(diffuse: str) -> str:
    """``diffuse`` if it names a model of ``DIFFUSE_MODELS``, else a ``ConfigError``."""
    if diffuse not in DIFFUSE_MODELS:
        from voxnero.errors import ConfigError

        raise ConfigError(f"unknown diffuse model {diffuse!r}",
                          fix=f"use one of {', '.join(DIFFUSE_MODELS)}")
    return diffuse


def principled_diffuse(n_dot_v: Tensor, n_dot_l: Tensor, l_dot_h: Tensor, roughness: Tensor
                       ) -> Tensor:
    """The factor W of the ``principled`` diffuse lobe ``albedo / pi * W`` (module docstring).

    Args:
        n_dot_v, n_dot_l: (..., 1) cosines to the view and light directions (clamped to
            [0, 1] here).
        l_dot_h: (..., 1) cosine between the light direction and the half vector.
        roughness: (..., 1) perceptual roughness r (not alpha).

    Returns:
        (..., 1) W >= 0: exactly 1 when both directions are normal; 0.25 when both graze a
        smooth surface (r = 0); up to 6.25 toward the light at grazing on a rough one (r = 1,
        v = l: the retro-reflection).
    """
    fv = (1.0 - n_dot_v.clamp(0.0, 1.0)) ** 5
    fl = (1.0 - n_dot_l.clamp(0.0, 1.0)) ** 5
    rr = 2.0 * roughness.clamp(0.0, 1.0) * l_dot_h.clamp(-1.0, 1.0) ** 2
    return (1.0 - 0.5 * fl) * (1.0 - 0.5 * fv) + rr * (fl + fv + fl * fv * (rr - 1.0))


def principled_diffuse_albedo(n_dot_v: Tensor, roughness: Tensor) -> Tensor:
    """Directional albedo of the ``principled`` diffuse lobe: the cosine integral over the
    light directions of ``W / pi`` (:func:`principled_diffuse`), in closed form.

    Split-sum shading of that lobe is ``albedo * P(n.v, r) * E(n) / pi`` (stage 1); it is exact
    under uniform light. With R_r = 2 r (l.h)^2 = r (1 + l.v), the azimuthal average of l.v
    is mu_l mu_v and of (l.v)^2 is mu_l^2 mu_v^2 + (1 - mu_l^2)(1 - mu_v^2) / 2, so every term
    reduces to the cosine moments <F> = 1/21, <mu F> = 1/84, <mu^2 F> = 1/252 of
    F = (1 - mu)^5 (``<g> = int_0^1 g(mu) 2 mu dmu``). At normal view P = 1 - 1/42 + 5 r / 84.

    Args:
        n_dot_v: (..., 1) cosine to the view direction (clamped to [0, 1]).
        roughness: (..., 1) perceptual roughness (clamped to [0, 1]).

    Returns:
        (..., 1) P > 0: 0.976-1.06 at normal view; at n.v = 0.1 about 0.75 (r = 0.1) to 1.31
        (r = 0.9), where the energy-weighted lobe's ``1 - E_d`` is 0.41 to 0.96.
    """
    mu = n_dot_v.clamp(0.0, 1.0)
    r = roughness.clamp(0.0, 1.0)
    fv = (1.0 - mu) ** 5
    a1, a2, a3 = 1.0 / 21.0, 1.0 / 84.0, 1.0 / 252.0
    rf = r * (a1 + mu * a2)                                   # <R_r F_l>
    r2f = r * r * (a1 + 2.0 * mu * a2 + mu * mu * a3 + 0.5 * (1.0 - mu * mu) * (a1 - a3))
    return ((1.0 - 0.5 * a1) * (1.0 - 0.5 * fv) + rf + r * (1.0 + 2.0 * mu / 3.0) * fv
            + fv * r2f - fv * rf)


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
    w = 1.0 - dielectric_albedo(n_dot_v, roughness)
    if n_dot_l is None:
        return w
    return w * (1.0 - dielectric_albedo(n_dot_l, roughness)) / (
        1.0 - dielectric_albedo_avg(roughness))


def brdf_eval(
    n: Tensor, v: Tensor, l: Tensor, albedo: Tensor, metallic: Tensor, roughness: Tensor,
    diffuse: str = "weighted",
) -> Tensor:
    """BRDF value f_r (per steradian, without the n.l cosine).

    f_r = (1 - m) W(v, l) albedo / pi + D G F / (4 n.v n.l), zero unless n.v > 0 and n.l > 0,
    with W the reciprocal energy weight ``diffuse_weight(n.v, r, n.l)`` ("weighted") or the
    ``principled`` diffuse factor (:func:`principled_diffuse`).
    Direction inputs are re-normalised (zero-length vectors give 0), so slightly non-unit
    inputs are fine.

    Args:
        n: (..., 3) unit surface normal.
        v: (..., 3) unit direction toward the viewer (away from the surface).
        l: (..., 3) unit direction toward the light (away from the surface).
        albedo: (..., 3) linear base colour.
        metallic: (..., 1) metalness in [0, 1].
        roughness: (..., 1) perceptual roughness r (alpha = r^2, clamped at ALPHA_MIN).
        diffuse: the diffuse lobe's convention, one of ``DIFFUSE_MODELS``.

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
    if diffuse == "principled":
        w = principled_diffuse(nv, nl, dot(l, h), roughness)
    else:
        w = diffuse_weight(nv, roughness, nl)
    diff = (1.0 - metallic) * w * albedo / math.pi
    upper = (nv > 0) & (nl > 0)
    return torch.where(upper, diff + spec, torch.zeros_like(spec))
