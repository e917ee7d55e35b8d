"""Equirectangular environment maps: direction <-> pixel mapping, lookup, filtering, sampling.

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


def _row_edges(H: int, dtype=torch.float64, device=None) -> Tensor:
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
    e = _row_edges(H, device=device)
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
    return _bilinear(img, dir_to_uv(d.to(torch.float64)))


def _bilinear(img: Tensor, uv: Tensor) -> Tensor:
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


# ----------------------------------------------------------------------------------------------
# Filtering: solid-angle-weighted mip chain, roughness lookup, SH irradiance (differentiable)
# ----------------------------------------------------------------------------------------------


def _theta_overlap(h_coarse: int, h_fine: int, device=None) -> Tensor:
    """(Hc, Hf) row weights: solid angle of the overlap of coarse and fine row cells."""
    ec = _row_edges(h_coarse, device=device)
    ef = _row_edges(h_fine, device=device)
    lo = torch.maximum(ec[:-1, None], ef[None, :-1])
    hi = torch.minimum(ec[1:, None], ef[None, 1:])
    w = (torch.cos(lo) - torch.cos(hi)).clamp_min(0.0)
    return w / w.sum(1, keepdim=True)


def _phi_overlap(w_coarse: int, w_fine: int, device=None) -> Tensor:
    """(Wc, Wf) column weights: overlap length of coarse and fine column cells."""
    ec = torch.arange(w_coarse + 1, dtype=torch.float64, device=device) / w_coarse
    ef = torch.arange(w_fine + 1, dtype=torch.float64, device=device) / w_fine
    lo = torch.maximum(ec[:-1, None], ef[None, :-1])
    hi = torch.minimum(ec[1:, None], ef[None, 1:])
    w = (hi - lo).clamp_min(0.0)
    return w / w.sum(1, keepdim=True)


def resample_area(img: Tensor, H: int, W: int) -> Tensor:
    """Solid-angle-weighted area resampling of an equirectangular map to (H, W).

    Each output cell is the solid-angle-weighted mean of the input cells it overlaps, so the
    integral of radiance over the sphere is preserved exactly. Differentiable w.r.t. ``img``.

    Args:
        img: (Hi, Wi, C) map.
        H, W: output size (H >= 2).

    Returns:
        (H, W, C) map.
    """
    At = _theta_overlap(H, img.shape[0], img.device).to(img.dtype)
    Ap = _phi_overlap(W, img.shape[1], img.device).to(img.dtype)
    return torch.einsum("ch,hwk,dw->cdk", At, img, Ap)


def mip_chain(img: Tensor, levels: int | None = None) -> list[Tensor]:
    """Area (solid-angle) weighted mip pyramid of an equirectangular map.

    Level k has H_k = (H_{k-1} - 1) // 2 + 1 rows (pole rows kept) and W_k = W_{k-1} // 2
    columns, down to H = 2 or ``levels`` levels. Every level integrates to the same total
    over the sphere. Differentiable (for learnable maps).

    Args:
        img: (H, W, C) linear radiance (or log-radiance made linear by the caller).
        levels: number of levels including level 0 (default: as many as possible).

    Returns:
        list of (H_k, W_k, C) tensors, level 0 = ``img``.
    """
    chain = [img]
    while levels is None or len(chain) < levels:
        h, w = chain[-1].shape[:2]
        hc, wc = (h - 1) // 2 + 1, max(w // 2, 1)
        if h <= 2 or hc < 2:
            break
        chain.append(resample_area(chain[-1], hc, wc))
    return chain


def roughness_to_level(roughness: Tensor, base_height: int, n_levels: int) -> Tensor:
    """Mip level for a GGX lobe: level = clamp(log2(2 alpha / dtheta_0), 0, L - 1).

    alpha = max(r^2, ALPHA_MIN) is (about) the angular half-width of the half-vector lobe, so
    the reflected lobe is ~2 alpha wide; level k's cells are dtheta_0 2^k wide with
    dtheta_0 = pi / (H_0 - 1) (0.7 deg at H = 256). E.g. H = 256: r = 0.1 -> 0.7, r = 0.3 -> 3.9,
    r = 1 -> 7.3 (clamped to the coarsest level).

    Args:
        roughness: (...) or (..., 1) perceptual roughness.
        base_height: H_0 of level 0.
        n_levels: number of levels L.

    Returns:
        fractional level, same shape as ``roughness``.
    """
    from voxnero.render.brdf import roughness_to_alpha

    alpha = roughness_to_alpha(roughness)
    dtheta0 = math.pi / (base_height - 1)
    return torch.log2(2.0 * alpha / dtheta0).clamp(0.0, float(n_levels - 1))


def lookup_rough(chain: list[Tensor], d: Tensor, roughness: Tensor) -> Tensor:
    """Roughness-filtered lookup: linear blend of the two mip levels around
    ``roughness_to_level(roughness)``. Differentiable w.r.t. the chain, d and roughness.

    Args:
        chain: output of ``mip_chain``.
        d: (..., 3) directions (e.g. reflected view directions).
        roughness: (..., 1) perceptual roughness.

    Returns:
        (..., C) filtered radiance (level 0 exactly while 2 alpha <= dtheta_0, i.e.
        r <= sqrt(dtheta_0 / 2) = 0.078 for H = 256).
    """
    lev = roughness_to_level(roughness, chain[0].shape[0], len(chain))  # (..., 1)
    return lookup_levels(chain, d, lev)


def lookup_levels(chain: list[Tensor], d: Tensor, level: Tensor) -> Tensor:
    """Bilinear lookup at a fractional mip level (linear blend of the two nearest levels).

    Args:
        chain: output of ``mip_chain``.
        d: (..., 3) directions.
        level: (...) or (..., 1) fractional level in [0, len(chain) - 1].

    Returns:
        (..., C) radiance; differentiable w.r.t. the chain, d and level.
    """
    L = len(chain)
    lead = d.shape[:-1]
    uv = dir_to_uv(d.reshape(-1, 3).to(torch.float64))
    lev = level
    if lev.dim() == len(lead):
        lev = lev.unsqueeze(-1)
    lev = lev.expand(*lead, 1).reshape(-1)
    out = torch.zeros(uv.shape[0], chain[0].shape[-1], dtype=chain[0].dtype, device=d.device)
    for k, img in enumerate(chain):
        w = (1.0 - (lev - k).abs()).clamp_min(0.0) if L > 1 else torch.ones_like(lev)
        sel = torch.nonzero(w > 0)[:, 0]  # each point touches at most two levels
        if sel.numel() == 0:
            continue
        out = out.index_add(0, sel, w[sel, None].to(out.dtype) * _bilinear(img, uv[sel]))
    return out.reshape(*lead, -1)


_SH_BAND_GAIN = (math.pi, 2.0 * math.pi / 3.0, math.pi / 4.0)


def sh9_project(img: Tensor) -> Tensor:
    """Project a map onto the 9 real SH of bands 0-2 (pixel-cell quadrature).

    Args:
        img: (H, W, C) linear radiance.

    Returns:
        (9, C) coefficients c_lm = sum L(d) y_lm(d) dOmega (``encoding.sh_basis`` ordering).
    """
    from voxnero.render.encoding import sh_basis

    H, W = img.shape[:2]
    Y = sh_basis(pixel_dirs(H, W, device=img.device, dtype=img.dtype), 2)  # (H, W, 9)
    om = pixel_solid_angles(H, W, device=img.device, dtype=img.dtype)
    return torch.einsum("hwk,hw,hwc->kc", Y, om, img)


def sh9_irradiance(coeffs: Tensor, n: Tensor) -> Tensor:
    """Irradiance E(n) = integral L(l) max(n.l, 0) dl from order-2 SH (Ramamoorthi-Hanrahan).

    Clamped at 0 (order-2 SH of a very peaked light can ring negative). Diffuse outgoing
    radiance is albedo / pi * E.

    Args:
        coeffs: (9, C) from ``sh9_project``.
        n: (..., 3) unit normals.

    Returns:
        (..., C) irradiance (W m^-2 sr^0 in radiance units times sr).
    """
    from voxnero.render.encoding import sh_basis

    Y = sh_basis(n.to(coeffs.dtype), 2)
    gain = torch.tensor([_SH_BAND_GAIN[0]] + [_SH_BAND_GAIN[1]] * 3 + [_SH_BAND_GAIN[2]] * 5,
                        dtype=coeffs.dtype, device=coeffs.device)
    return ((Y * gain) @ coeffs).clamp_min(0.0)


def luminance(rgb: Tensor) -> Tensor:
    """Rec. 709 luminance of linear RGB: (..., 3) -> (...)."""
    return rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722


# ----------------------------------------------------------------------------------------------
# A fixed HDR environment map
# ----------------------------------------------------------------------------------------------

#: roughness nodes of ``EnvMap.prefiltered`` (linear interpolation in between)
PREFILTER_ROUGHNESS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5, 0.65, 0.8, 1.0)


class EnvMap:
    """A fixed linear HDR equirectangular environment map, +Z up (see the module docstring).

    Lookups, luminance importance sampling (pdf per steradian), GGX-prefiltered radiance for the
    split-sum approximation and cosine-convolved irradiance. ``up``/``yaw_deg`` re-orient the
    map (``rotate_dirs``): all methods take and return *world* directions.

    Args:
        img: (H, W, 3) linear radiance (numpy or torch).
        up: world up axis of the map ("z" default).
        yaw_deg: rotation of the environment about its up axis.
        device: torch device (default: that of ``img``).
    """

    def __init__(self, img, up: str = "z", yaw_deg: float = 0.0, device=None):
        img = torch.as_tensor(img, dtype=torch.float32)
        if device is not None:
            img = img.to(device)
        if img.ndim != 3 or img.shape[2] != 3 or img.shape[0] < 2:
            from voxnero.errors import DataError

            raise DataError(f"env map must be (H, W, 3) with H >= 2, got {tuple(img.shape)}",
                            fix="pass an equirectangular RGB image")
        self.img = img.clamp_min(0.0)
        self.up, self.yaw_deg = up, yaw_deg
        eye = torch.eye(3, dtype=torch.float64)
        self._M = rotate_dirs(eye, up, yaw_deg).T.to(torch.float32).to(img.device)  # world->map
        self._identity = bool(torch.allclose(self._M.cpu(), torch.eye(3)))
        self._sampler = None
        self._prefilter = None
        self._irr = None

    # -- construction / io
    @classmethod
    def from_file(cls, path, up: str = "z", yaw_deg: float = 0.0, scale: float = 1.0,
                  device=None) -> EnvMap:
        """Read an ``.exr``/``.hdr`` map with ``voxnero.io.exr.read_envmap`` (times ``scale``).

        Raises:
            DataError: unreadable, or smaller than 2 x 2 pixels (naming the file).
        """
        from voxnero.errors import DataError
        from voxnero.io.exr import read_envmap

        img = torch.from_numpy(read_envmap(path)) * scale
        if img.shape[0] < 2 or img.shape[1] < 2:
            raise DataError(f"the env map is {img.shape[1]} x {img.shape[0]} pixels: an "
                            "equirectangular map needs at least 2 rows and 2 columns",
                            path=path, fix="pass an equirectangular HDR map (width = 2 x "
                            "height, e.g. 1024 x 512)")
        return cls(img, up=up, yaw_deg=yaw_deg, device=device)

    def save(self, path) -> None:
        """Write the map (in its own +Z-up frame) as a 32-bit float EXR."""
        from voxnero.io.exr import write_exr

        write_exr(path, self.img.detach().cpu().numpy(), half=False)

    @property
    def device(self) -> torch.device:
        return self.img.device

    def to(self, device) -> EnvMap:
        """A copy on ``device`` (precomputed tables are rebuilt lazily there)."""
        return EnvMap(self.img, up=self.up, yaw_deg=self.yaw_deg, device=device)

    def _to_map(self, d: Tensor) -> Tensor:
        return d if self._identity else d @ self._M.to(d.dtype).T

    def _to_world(self, d: Tensor) -> Tensor:
        return d if self._identity else d @ self._M.to(d.dtype)

    # -- queries
    def lookup(self, d: Tensor) -> Tensor:
        """Bilinear radiance along world directions d (..., 3) -> (..., 3)."""
        return envmap_lookup(self.img, self._to_map(d))

    __call__ = lookup

    def _build_sampler(self) -> None:
        H, W = self.img.shape[:2]
        om = pixel_solid_angles(H, W, device=self.device, dtype=torch.float64)
        lum = luminance(self.img.double()).clamp_min(0.0)
        # energy of the *bilinear* interpolant over each cell: separable [1, 6, 1] / 8 filter
        # (a hot pixel spreads into its neighbours' cells; uniform-in-cell sampling of the
        # plain pixel values would leave 44 % of its energy to the other strategies)
        lum = (lum.roll(1, 1) + 6.0 * lum + lum.roll(-1, 1)) / 8.0
        up = torch.cat([lum[:1], lum[:-1]], 0)
        down = torch.cat([lum[1:], lum[-1:]], 0)
        lum = (up + 6.0 * lum + down) / 8.0
        w = om * (lum + 1e-2 * (lum * om).sum() / (4.0 * math.pi) + 1e-12)
        p = w / w.sum()
        self._sampler = {
            "p": p, "om": om, "flat": p.reshape(-1),
            "cdf": torch.cumsum(p.reshape(-1), 0),
            "cos_edges": torch.cos(_row_edges(H, device=self.device)),
        }

    def sample(self, u: Tensor) -> tuple[Tensor, Tensor]:
        """Sample directions proportionally to luminance x solid angle (piecewise constant).

        Args:
            u: (N, 2) uniforms in [0, 1).

        Returns:
            dirs (N, 3) world unit directions, pdf (N,) per steradian (matches ``pdf``).
        """
        if self._sampler is None:
            self._build_sampler()
        s = self._sampler
        H, W = self.img.shape[:2]
        u = u.to(torch.float64).clamp(0.0, 1.0 - 1e-12)
        # one binary search over the flattened cell CDF; the remainder of u0 within the chosen
        # cell is reused for the position in theta, u1 for the position in phi
        k = torch.searchsorted(s["cdf"], u[:, 0].contiguous(), right=True).clamp(max=H * W - 1)
        pk = s["flat"][k]
        u0 = ((u[:, 0] - (s["cdf"][k] - pk)) / pk.clamp_min(1e-300)).clamp(0.0, 1.0)
        u1 = u[:, 1]
        j, i = k // W, k % W
        c_lo, c_hi = s["cos_edges"][j], s["cos_edges"][j + 1]
        cos_t = (c_lo - u0 * (c_lo - c_hi)).clamp(-1.0, 1.0)
        sin_t = torch.sqrt((1.0 - cos_t * cos_t).clamp_min(0.0))
        phi = 2.0 * math.pi * (i.to(torch.float64) + u1) / W
        d = torch.stack([sin_t * torch.sin(phi), sin_t * torch.cos(phi), cos_t], -1)
        pdf = s["p"][j, i] / s["om"][j, i]
        return self._to_world(d.float()), pdf.float()

    def pdf(self, d: Tensor) -> Tensor:
        """Pdf per steradian of ``sample`` at world directions d (..., 3) -> (...)."""
        if self._sampler is None:
            self._build_sampler()
        s = self._sampler
        H, W = self.img.shape[:2]
        theta, phi = dir_to_theta_phi(self._to_map(d).to(torch.float64))
        j = torch.floor(theta / (math.pi / (H - 1)) + 0.5).long().clamp(0, H - 1)
        i = torch.floor(phi / (2.0 * math.pi) * W).long().clamp(0, W - 1)
        return (s["p"][j, i] / s["om"][j, i]).to(d.dtype)

    # -- filtered versions for the split-sum approximation
    def _build_prefilter(self, n_samples: int = 32) -> None:
        from voxnero.render.brdf import roughness_to_alpha
        from voxnero.render.sampling import sample_ggx_vndf
        from voxnero.render.splitsum import hammersley

        H0, W0 = self.img.shape[:2]
        chain = mip_chain(self.img)
        u = hammersley(n_samples, torch.float32).to(self.device)
        om0 = 4.0 * math.pi / (H0 * W0)
        maps = [self.img]
        for r in PREFILTER_ROUGHNESS[1:]:
            lev = int(roughness_to_level(torch.tensor(r), H0, len(chain)).floor())
            # output resolution follows the lobe width (at most 128 x 256, at least 16 x 32)
            ho = min(128, max(16, (H0 - 1) // (2**lev) + 1))
            wo = 2 * ho
            n = pixel_dirs(ho, wo, device=self.device).reshape(-1, 1, 3)
            a = float(roughness_to_alpha(torch.tensor(r)))
            acc = torch.zeros(n.shape[0], 3, device=self.device)
            wsum = torch.zeros(n.shape[0], 1, device=self.device)
            nn_ = n.expand(-1, n_samples, 3).reshape(-1, 3)
            uu = u.repeat(n.shape[0], 1)
            for s0 in range(0, nn_.shape[0], 1 << 18):
                nb = nn_[s0:s0 + (1 << 18)]
                ub = uu[s0:s0 + (1 << 18)]
                l, pdf = sample_ggx_vndf(ub, nb, nb, a)
                cos = (l * nb).sum(-1).clamp_min(0.0)
                # filtered importance sampling (Krivanek & Colbert 2008): mip level by pdf
                lev_s = (0.5 * torch.log2(1.0 / (n_samples * pdf.clamp_min(1e-12) * om0)) + 1.0)
                val = lookup_levels(chain, l, lev_s.clamp(0.0, len(chain) - 1))
                idx = torch.arange(s0, s0 + nb.shape[0], device=self.device) // n_samples
                acc.index_add_(0, idx, val * cos[:, None])
                wsum.index_add_(0, idx, cos[:, None])
            maps.append((acc / wsum.clamp_min(1e-12)).reshape(ho, wo, 3))
        self._prefilter = maps

    def prefiltered(self, d: Tensor, roughness: Tensor) -> Tensor:
        """GGX-prefiltered radiance around direction d (n = v = d assumption, weighted by n.l).

        Precomputed at ``PREFILTER_ROUGHNESS`` by filtered importance sampling (32 GGX samples
        per texel, mip level from the sample pdf; first call with r > 0 on a 512 x 256 map:
        ~8 s on one busy core) and interpolated linearly in roughness; roughness 0 is the map
        itself (no precomputation needed while all roughness values are 0).

        Args:
            d: (..., 3) world directions (usually the reflected view direction).
            roughness: (..., 1) perceptual roughness.

        Returns:
            (..., 3) radiance.
        """
        r = roughness.clamp(0.0, 1.0)
        if self._prefilter is None:
            if not bool((r > 0).any()):
                return self.lookup(d) * torch.ones_like(r)
            self._build_prefilter()
        nodes = torch.tensor(PREFILTER_ROUGHNESS, dtype=d.dtype, device=d.device)
        dm = self._to_map(d)
        k = (torch.searchsorted(nodes, r.contiguous(), right=True) - 1).clamp(0, len(nodes) - 2)
        r0, r1 = nodes[k], nodes[k + 1]
        t = ((r - r0) / (r1 - r0)).clamp(0.0, 1.0)
        out = 0.0
        for idx, img in enumerate(self._prefilter):
            w = torch.where(k == idx, 1.0 - t, torch.zeros_like(t))
            w = w + torch.where(k + 1 == idx, t, torch.zeros_like(t))
            if bool((w > 0).any()):
                out = out + w * envmap_lookup(img, dm)
        return out

    def irradiance(self, n: Tensor) -> Tensor:
        """Cosine-convolved irradiance E(n) = integral L(l) max(n.l, 0) dl (exact convolution of
        a 64 x 128 area-downsampled copy, tabulated at 32 x 64 and looked up bilinearly).

        Args:
            n: (..., 3) world unit normals.

        Returns:
            (..., 3) irradiance; diffuse outgoing radiance is albedo / pi * E.
        """
        if self._irr is None:
            src = resample_area(self.img.double(), 64, 128)
            ds = pixel_dirs(64, 128, device=self.device, dtype=torch.float64).reshape(-1, 3)
            om = pixel_solid_angles(64, 128, device=self.device, dtype=torch.float64).reshape(-1)
            no = pixel_dirs(32, 64, device=self.device, dtype=torch.float64).reshape(-1, 3)
            cos = (no @ ds.T).clamp_min(0.0)
            self._irr = (cos @ (src.reshape(-1, 3) * om[:, None])).reshape(32, 64, 3).float()
        return envmap_lookup(self._irr, self._to_map(n))
