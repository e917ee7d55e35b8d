"""Stage-1 colour from the rendering equation (split-sum GGX + Lambert), pure functions.

Outgoing linear radiance toward the camera at a surface point with unit normal ``n``::

    c = (1 − m)·W(n·v, r)·albedo·L_diff(n)  +  (F0·A + B)·L_spec(r, roughness)

with ``F0 = 0.04 (1 − m) + m·albedo``, ``(A, B)`` the split-sum terms of GGX for ``n·v`` and
perceptual roughness (α = r²), ``r`` the mirror reflection of the view direction,
``L_spec`` the incoming light pre-filtered by roughness and ``L_diff = E(n)/π`` the cosine-weighted
incoming radiance (NeRO, stage 1), and ``W`` the diffuse lobe's directional albedo
(``diffuse`` of :func:`shade`).
"""

from __future__ import annotations

import torch

from voxnero.render.brdf import check_diffuse, diffuse_weight, principled_diffuse_albedo
from voxnero.render.microfacet import f0_from
from voxnero.render.splitsum import specular_split_sum


def reflect(d: torch.Tensor, n: torch.Tensor) -> torch.Tensor:
    """Mirror direction of a ray travelling along ``d`` off a surface with normal ``n``.

    Args:
        d: ``(N, 3)`` unit ray directions (camera → surface).
        n: ``(N, 3)`` unit normals.

    Returns:
        ``(N, 3)`` unit reflected directions (surface → environment), ``d − 2 (d·n) n``.
    """
    return d - 2.0 * (d * n).sum(-1, keepdim=True) * n


def shade(n: torch.Tensor, d: torch.Tensor, albedo: torch.Tensor, metallic: torch.Tensor,
          roughness: torch.Tensor, spec_light: torch.Tensor, diff_light: torch.Tensor,
          diffuse: str = "weighted") -> torch.Tensor:
    """Split-sum shading.

    Args:
        n: ``(N, 3)`` unit normals; d: ``(N, 3)`` unit ray directions (camera → surface).
        albedo: ``(N, 3)`` linear base colour; metallic: ``(N, 1)``; roughness: ``(N, 1)``
            perceptual.
        spec_light: ``(N, 3)`` linear radiance along the reflected direction, pre-filtered for
            ``roughness``.
        diff_light: ``(N, 3)`` cosine-weighted radiance ``E(n)/π``.
        diffuse: the diffuse lobe (``render.brdf.DIFFUSE_MODELS``): "weighted" scales it by
            ``1 − E_d(n·v)``, what the dielectric interface does not reflect; "principled" by
            the directional albedo of the Disney (Burley 2015) lobe,
            ``principled_diffuse_albedo(n·v, r)``, brighter at grazing views.

    Returns:
        ``(N, 3)`` linear outgoing radiance.
    """
    n_dot_v = (-(d * n).sum(-1, keepdim=True)).clamp(1e-4, 1.0)
    if check_diffuse(diffuse) == "principled":
        w = principled_diffuse_albedo(n_dot_v, roughness)
    else:  # what the dielectric interface does not reflect (render/brdf.py)
        w = diffuse_weight(n_dot_v, roughness)
    return (1.0 - metallic) * w * albedo * diff_light + specular_split_sum(
        f0_from(albedo, metallic), n_dot_v, roughness, spec_light)
