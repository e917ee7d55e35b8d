"""Equirectangular (lat-long) maps: the direction <-> pixel convention, pixel grid, lookup.

Convention (docs/ARCHITECTURE.md, the dev scenes' Mitsuba mapping), +Z up, linear HDR
``(H, W, 3)`` maps. For a unit world direction d pointing from the object to the environment::

    u = atan2(dx, dy) / (2 pi)  wrapped to [0, 1),      v = arccos(dz) / pi
    x = u * W - 0.5  (periodic),                        y = v * (H - 1)  (clamped)

so pixel (column i, row j) is the radiance from theta = pi j / (H - 1), phi = 2 pi (i + 0.5) / W,
d = (sin theta sin phi, sin theta cos phi, cos theta). Row 0 is the zenith, row H-1 the nadir.
Pixel (i, j) "owns" the cell phi in [2 pi i / W, 2 pi (i + 1) / W], theta in
[theta_j - dt/2, theta_j + dt/2] clipped to [0, pi] (dt = pi / (H - 1)); these cells tile the
sphere and define the solid angles, the mip chain and the importance-sampling pdf.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def dir_to_theta_phi(d: Tensor) -> tuple[Tensor, Tensor]:
    """Polar angle theta in [0, pi] from +Z and azimuth phi in [0, 2 pi) (phi = atan2(dx, dy)).

    Safe at the poles and for zero-length vectors (finite values and gradients).

    Args:
        d: (..., 3) directions (need not be unit).

    Returns:
        theta (...,), phi (...,), radians.
    """
    dx, dy, dz = d.unbind(-1)
    r2 = dx * dx + dy * dy
    small = r2 < 1e-24
    rho = torch.sqrt(torch.where(small, torch.ones_like(r2), r2))
    rho = torch.where(small, torch.zeros_like(rho), rho)
    theta = torch.atan2(rho, dz)
    sx = torch.where(small, torch.zeros_like(dx), dx)
    sy = torch.where(small, torch.ones_like(dy), dy)
    phi = torch.atan2(sx, sy)
    phi = torch.where(phi < 0, phi + 2.0 * math.pi, phi)
    return theta, phi


def dir_to_uv(d: Tensor) -> Tensor:
    """Direction -> (u, v) in [0, 1)^2 x [0, 1], the Mitsuba equirectangular mapping.

    Args:
        d: (..., 3) world directions (normalised internally; +Z up).

    Returns:
        (..., 2) uv with u = atan2(dx, dy) / 2 pi wrapped to [0, 1), v = arccos(dz) / pi.
    """
    theta, phi = dir_to_theta_phi(d)
    u = phi / (2.0 * math.pi)
    u = u - torch.floor(u)
    return torch.stack([u, theta / math.pi], dim=-1)


def uv_to_dir(uv: Tensor) -> Tensor:
    """(u, v) -> unit direction, inverse of ``dir_to_uv``.

    Args:
        uv: (..., 2).

    Returns:
        (..., 3) unit directions (sin t sin p, sin t cos p, cos t), t = pi v, p = 2 pi u.
    """
    theta = uv[..., 1] * math.pi
    phi = uv[..., 0] * (2.0 * math.pi)
    st = torch.sin(theta)
    return torch.stack([st * torch.sin(phi), st * torch.cos(phi), torch.cos(theta)], dim=-1)


def pixel_dirs(H: int, W: int, device=None, dtype=torch.float32) -> Tensor:
    """Directions of the env-map pixel centres.

    Args:
        H, W: map size.

    Returns:
        (H, W, 3) unit directions; row j at theta = pi j / (H - 1), column i at
        phi = 2 pi (i + 0.5) / W.
    """
    j = torch.arange(H, device=device, dtype=torch.float64)
    i = torch.arange(W, device=device, dtype=torch.float64)
    theta = (math.pi * j / (H - 1))[:, None].expand(H, W)
    phi = (2.0 * math.pi * (i + 0.5) / W)[None, :].expand(H, W)
    st = torch.sin(theta)
    d = torch.stack([st * torch.sin(phi), st * torch.cos(phi), torch.cos(theta)], dim=-1)
    return d.to(dtype)


def row_edges(H: int, dtype=torch.float64, device=None) -> Tensor:
    """(H + 1,) theta edges of the row cells: 0, dt/2, 3dt/2, ..., pi."""
    dt = math.pi / (H - 1)
    e = (torch.arange(H + 1, dtype=dtype, device=device) - 0.5) * dt
    return e.clamp(0.0, math.pi)


def pixel_solid_angles(H: int, W: int, device=None, dtype=torch.float32) -> Tensor:
    """Solid angle of each pixel's cell (rows centred on theta_j, pole rows half-height).

    Args:
        H, W: map size.

    Returns:
        (H, W) steradians; the sum is exactly 4 pi.
    """
    e = row_edges(H, device=device)
    band = torch.cos(e[:-1]) - torch.cos(e[1:])
    omega = band * (2.0 * math.pi / W)
    return omega[:, None].expand(H, W).to(dtype).contiguous()


def envmap_lookup(img: Tensor, d: Tensor) -> Tensor:
    """Bilinear lookup of an equirectangular map; differentiable w.r.t. ``img`` and ``d``.

    Args:
        img: (H, W, C) linear radiance (C = 3 usually).
        d: (..., 3) world directions (normalised internally).

    Returns:
        (..., C) radiance, dtype of ``img``; the pixel value at a pixel-centre direction
        (exactly, up to float64 rounding, except on the pole rows where all columns
        share one direction).
    """
    # pixel coordinates in float64: float32 atan2 would blend ~1e-5 of the neighbour pixel
    return bilinear(img, dir_to_uv(d.to(torch.float64)))


def bilinear(img: Tensor, uv: Tensor) -> Tensor:
    """Bilinear sample of (H, W, C) at (..., 2) uv (x periodic, y clamped) -> (..., C)."""
    H, W = img.shape[0], img.shape[1]
    x = uv[..., 0] * W - 0.5
    y = (uv[..., 1] * (H - 1)).clamp(0.0, H - 1)
    x0f = torch.floor(x)
    wx = (x - x0f).unsqueeze(-1).to(img.dtype)
    x0 = x0f.long() % W
    x1 = (x0 + 1) % W
    y0 = torch.floor(y).clamp(max=max(H - 2, 0))
    wy = (y - y0).unsqueeze(-1).to(img.dtype)
    y0 = y0.long()
    y1 = (y0 + 1).clamp(max=H - 1)
    flat = img.reshape(H * W, -1)

    def g(yy: Tensor, xx: Tensor) -> Tensor:
        idx = (yy * W + xx).reshape(-1)
        return flat[idx].reshape(*yy.shape, flat.shape[-1])

    top = g(y0, x0) * (1 - wx) + g(y0, x1) * wx
    bot = g(y1, x0) * (1 - wx) + g(y1, x1) * wx
    return top * (1 - wy) + bot * wy


_AXES = {
    "z": torch.eye(3, dtype=torch.float64),
    # y-up input frame (e.g. glTF / OpenGL worlds): (x, y, z)_yup -> (x, -z, y)_zup
    "y": torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]], dtype=torch.float64),
    "-y": torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]], dtype=torch.float64),
    "x": torch.tensor([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64),
    "-z": torch.tensor([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]], dtype=torch.float64),
}


def rotate_dirs(d: Tensor, up: str = "z", yaw_deg: float = 0.0) -> Tensor:
    """Express world directions in the env map's +Z-up frame, then turn the map by a yaw.

    ``up`` names the world axis that is "up" for the map ("z" = identity, "y": a +Y-up world,
    "-y", "x", "-z"); the direction is rotated so that this axis becomes +Z. ``yaw_deg`` then
    turns the environment about its up axis: the map feature at azimuth phi = atan2(dx, dy)
    appears in the world at azimuth phi - yaw (its u coordinate is seen at u - yaw / 360).

    Args:
        d: (..., 3) directions.
        up: up axis of the world the directions are expressed in.
        yaw_deg: rotation of the environment about its up axis, degrees.

    Returns:
        (..., 3) directions to pass to ``envmap_lookup``.
    """
    if up not in _AXES:
        from voxnero.errors import ConfigError

        raise ConfigError(f"unknown env-map up axis {up!r}", fix=f"use one of {sorted(_AXES)}")
    R = _AXES[up]
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    Rz = torch.tensor([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    M = (Rz @ R).to(d.dtype).to(d.device)
    return d @ M.T


def latlong_blur(img: Tensor, sigma: float) -> Tensor:
    """Gaussian blur of a lat-long map in pixel units: periodic in u, clamped at the poles.

    Used on stage 2's env-map *updates* (``material.light.update_smooth``). A constant map is
    unchanged and the kernel sums to 1, so a blurred step is a positive-definite
    preconditioning of the plain one: it spreads each step over neighbouring pixels without
    changing where the optimisation stops.

    Args:
        img: (H, W, C) map (any values: linear, log, or a difference of two maps).
        sigma: standard deviation in pixels of this map (same in u and v); <= 0 returns img.

    Returns:
        (H, W, C) blurred map.
    """
    if sigma <= 0:
        return img
    from kornia.filters import gaussian_blur2d

    r = max(1, int(math.ceil(2.0 * sigma)))
    x = img.permute(2, 0, 1)[None]
    x = torch.cat([x[..., -r:], x, x[..., :r]], dim=-1)  # wrap in u; kornia pads v (replicate)
    y = gaussian_blur2d(x, (2 * r + 1, 2 * r + 1), (float(sigma), float(sigma)),
                        border_type="replicate")
    return y[..., r:-r][0].permute(1, 2, 0)
