"""Lights of stage 2: the start and clamp of the learnable HDR env map, and a cheap indirect-light
estimate.

Direct light: :class:`voxnero.fields.lights.EnvLight` (the one learnable env map of both stages),
started from the photos' background pixels (:func:`init_from_background`) and clamped to
[``LOG_MIN``, ``LOG_MAX``]; its ``image()`` is the linear HDR map that is exported as is.

Indirect light (radiance arriving along a secondary ray that hits the object): the outgoing
radiance of the hit point toward the ray's origin, estimated from the current material with a
low-order light and no further bounce:

    L_o(y, w) = (1 − m) · (1 − E_d) · albedo · E(n_y) / π + L_blur(reflect(w, n_y)) · (F0 · A + B)

(without the factor 1 − E_d for the ``principled`` diffuse convention), with E the irradiance
from the map's order-2 spherical-harmonic projection (``voxnero.render.sh``, Ramamoorthi and
Hanrahan 2001), L_blur the map average-pooled to ``8 × 16`` and (A, B) the split-sum terms
(``voxnero.render.splitsum``).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from voxnero.render.brdf import check_diffuse, diffuse_weight
from voxnero.render.latlong import dir_to_uv, envmap_lookup
from voxnero.render.microfacet import f0_from
from voxnero.render.sh import sh9_irradiance, sh9_project
from voxnero.render.splitsum import specular_split_sum

LOG_MIN, LOG_MAX = -12.0, 8.0
"""Stage 2's clamp of the env light's log radiance, ``EnvLight(min_log=LOG_MIN, max_log=LOG_MAX)``
(linear 6e-6 .. 3e3; stage 1 clamps only above, at its ``light.max_log_radiance``)."""


def _cells(dirs: Tensor, height: int) -> Tensor:
    """(M,) flat index of the env-map cell (nearest pixel) of each unit direction, (M, 3)."""
    H, W = height, 2 * height
    uv = dir_to_uv(dirs.double())
    x = torch.floor(uv[:, 0] * W).long() % W
    y = torch.round(uv[:, 1] * (H - 1)).long().clamp(0, H - 1)
    return y * W + x


def background_coverage(dirs: Tensor, height: int) -> Tensor:
    """How many background pixels look along each env-map cell (nearest pixel).

    Args:
        dirs: (M, 3) unit directions of the photos' background pixels.
        height: map height H (width 2H).

    Returns:
        (H, 2H) float counts; 0 where the photos never see the environment directly (there
        the map is learned only through the object's reflections and shading).
    """
    idx = _cells(dirs.cpu(), height)
    return torch.bincount(idx, minlength=2 * height * height).float().view(height, 2 * height)


def init_from_background(dirs: Tensor, rgb: Tensor, height: int) -> Tensor:
    """Average background pixels into env-map cells (nearest pixel); unseen cells get the mean.

    Args:
        dirs: (M, 3) unit directions toward the environment.
        rgb: (M, 3) linear radiance seen along them.
        height: map height H (width 2H).

    Returns:
        (H, 2H, 3) linear map.
    """
    H, W = height, 2 * height
    idx = _cells(dirs, height)
    out = torch.zeros(H * W, 3).index_add_(0, idx, rgb.float())
    cnt = torch.bincount(idx, minlength=H * W).float()
    seen = cnt > 0
    mean = out[seen].sum(0) / cnt[seen].sum() if seen.any() else torch.full((3,), 0.5)
    out = torch.where(seen[:, None], out / cnt.clamp_min(1)[:, None], mean)
    return out.view(H, W, 3)


class IndirectLight:
    """Outgoing radiance of secondary hits from the current material and env map (see module):
    analytic, no parameters of its own (stage 1's learned counterpart is
    :class:`voxnero.fields.lights.IndirectNet`).

    Built once per training step from the current env image (keeps gradients to it).
    """

    def __init__(self, env_image: Tensor, blur_height: int = 8, diffuse: str = "weighted"):
        """Args:
            env_image: (H, W, 3) current linear env map.
            blur_height: height of the average-pooled map used for the specular part.
            diffuse: the BRDF's diffuse convention (``voxnero.render.brdf.DIFFUSE_MODELS``):
                "weighted" scales the diffuse part by 1 − E_d (the energy weight integrated
                over the light); "principled" leaves it at 1 (its lobe is not weighted; its
                retro-reflection is left out of this low-order estimate).
        """
        self.weighted = check_diffuse(diffuse) == "weighted"
        self.sh = sh9_project(env_image)
        H = env_image.shape[0]
        k = max(1, H // blur_height)
        img = env_image.permute(2, 0, 1)[None]
        self.blur = F.avg_pool2d(img, k, k)[0].permute(1, 2, 0)

    def radiance(self, n: Tensor, w: Tensor, albedo: Tensor, metallic: Tensor,
                 roughness: Tensor) -> Tensor:
        """L_o at hit points toward unit directions w (away from the hit).

        Args:
            n: (N, 3) unit shading normals at the hits; w: (N, 3) unit directions toward the
                ray's origin; albedo (N, 3), metallic (N, 1), roughness (N, 1).

        Returns:
            (N, 3) linear radiance (>= 0).
        """
        E = sh9_irradiance(self.sh, n)
        nw = (n * w).sum(-1, keepdim=True)
        r = 2 * nw * n - w
        spec = specular_split_sum(f0_from(albedo, metallic), nw.clamp_min(0.0), roughness,
                                  envmap_lookup(self.blur, r))
        w = diffuse_weight(nw.clamp_min(0.0), roughness) if self.weighted else 1.0
        diff = (1 - metallic) * w * albedo * E / math.pi
        return torch.where(nw > 0, diff + spec, torch.zeros_like(diff))
