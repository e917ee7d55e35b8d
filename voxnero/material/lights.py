"""Lights of stage 2: the explicit learnable HDR env map and a cheap indirect-light estimate.

Direct light: an equirectangular map of log radiance ``(H, W, 3)``, W = 2H, in the project's
env-map convention (docs/ARCHITECTURE.md: u = atan2(dx, dy) / 2π, v = arccos(dz) / π,
x = u·W − 0.5, y = v·(H − 1), +Z up). ``image()`` is the linear HDR map that is exported as is.

Indirect light (radiance arriving along a secondary ray that hits the object): the outgoing
radiance of the hit point toward the ray's origin, estimated from the current material with a
low-order light and no further bounce:

    L_o(y, w) = (1 − m) · (1 − E_d) · albedo · E(n_y) / π + L_blur(reflect(w, n_y)) · (F0 · A + B)

with E the irradiance from the map's order-2 spherical-harmonic projection (Ramamoorthi and
Hanrahan 2001), L_blur the map average-pooled to ``8 × 16`` and (A, B) the split-sum terms
(``voxnero.render.splitsum``).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from voxnero.render.brdf import diffuse_weight, f0_from
from voxnero.render.envmap import envmap_lookup, pixel_dirs, pixel_solid_angles
from voxnero.render.splitsum import specular_split_sum

LOG_MIN, LOG_MAX = -12.0, 8.0
"""Bounds of the log radiance (linear 6e-6 .. 3e3)."""


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
    out = torch.zeros(H * W, 3)
    cnt = torch.zeros(H * W)
    if dirs.shape[0]:
        from voxnero.render.envmap import dir_to_uv

        uv = dir_to_uv(dirs.double())
        x = torch.floor(uv[:, 0] * W).long() % W
        y = torch.round(uv[:, 1] * (H - 1)).long().clamp(0, H - 1)
        idx = y * W + x
        out.index_add_(0, idx, rgb.float())
        cnt.index_add_(0, idx, torch.ones_like(idx, dtype=torch.float32))
    seen = cnt > 0
    mean = out[seen].sum(0) / cnt[seen].sum() if seen.any() else torch.full((3,), 0.5)
    out = torch.where(seen[:, None], out / cnt.clamp_min(1)[:, None], mean)
    return out.view(H, W, 3)


class EnvLight(nn.Module):
    """Learnable equirectangular HDR env map, parameterised by its log radiance."""

    def __init__(self, image: Tensor):
        """Args:
            image: (H, W, 3) initial linear radiance (W = 2H).
        """
        super().__init__()
        self.log_rad = nn.Parameter(torch.log(image.float().clamp_min(1e-4)))

    @property
    def height(self) -> int:
        return int(self.log_rad.shape[0])

    def image(self) -> Tensor:
        """(H, W, 3) linear HDR map (differentiable)."""
        return torch.exp(self.log_rad.clamp(LOG_MIN, LOG_MAX))

    def lookup(self, d: Tensor) -> Tensor:
        """Bilinear radiance along unit directions d (..., 3) -> (..., 3)."""
        return envmap_lookup(self.image(), d)

    def upsampled(self, height: int) -> EnvLight:
        """A new EnvLight at ``height``: the log map looked up (bilinear, same convention) at the
        new pixel-centre directions."""
        d = pixel_dirs(height, 2 * height, device=self.log_rad.device)
        return EnvLight(torch.exp(envmap_lookup(self.log_rad.detach(), d)))

    def smoothness(self) -> Tensor:
        """Mean squared difference of neighbouring log-radiance pixels (periodic in u)."""
        lr = self.log_rad
        dx = lr - torch.roll(lr, 1, dims=1)
        dy = lr[1:] - lr[:-1]
        return (dx**2).mean() + (dy**2).mean()


def sh_basis(d: Tensor) -> Tensor:
    """Real spherical harmonics up to order 2 at unit directions: (..., 3) -> (..., 9)."""
    x, y, z = d.unbind(-1)
    return torch.stack([
        torch.full_like(x, 0.282095),
        0.488603 * y, 0.488603 * z, 0.488603 * x,
        1.092548 * x * y, 1.092548 * y * z, 0.315392 * (3 * z * z - 1),
        1.092548 * x * z, 0.546274 * (x * x - y * y)], -1)


def irradiance_sh(image: Tensor) -> Tensor:
    """Order-2 SH coefficients of the irradiance of an env map (cosine lobe convolved).

    Args:
        image: (H, W, 3) linear radiance.

    Returns:
        (9, 3) coefficients c such that E(n) = sh_basis(n) @ c (irradiance, W/m² analogue).
    """
    H, W = image.shape[:2]
    d = pixel_dirs(H, W, device=image.device)
    w = pixel_solid_angles(H, W, device=image.device)
    Y = sh_basis(d) * w[..., None]
    L = torch.einsum("hwk,hwc->kc", Y, image)
    A = torch.tensor([math.pi] + [2 * math.pi / 3] * 3 + [math.pi / 4] * 5,
                     device=image.device, dtype=image.dtype)
    return L * A[:, None]


class IndirectLight:
    """Outgoing radiance of secondary hits from the current material and env map (see module):
    analytic, no parameters of its own (stage 1's learned counterpart is
    :class:`voxnero.fields.lights.IndirectNet`).

    Built once per training step from the current env image (keeps gradients to it).
    """

    def __init__(self, env_image: Tensor, blur_height: int = 8):
        """Args:
            env_image: (H, W, 3) current linear env map.
            blur_height: height of the average-pooled map used for the specular part.
        """
        self.sh = irradiance_sh(env_image)
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
        E = (sh_basis(n) @ self.sh).clamp_min(0.0)
        nw = (n * w).sum(-1, keepdim=True)
        r = 2 * nw * n - w
        spec = specular_split_sum(f0_from(albedo, metallic), nw.clamp_min(0.0), roughness,
                                  envmap_lookup(self.blur, r))
        diff = (1 - metallic) * diffuse_weight(nw.clamp_min(0.0), roughness) * albedo * E / math.pi
        return torch.where(nw > 0, diff + spec, torch.zeros_like(diff))
