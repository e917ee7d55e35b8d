"""A fixed linear HDR environment map (``EnvMap``): lookups in any world orientation, luminance
importance sampling, GGX-prefiltered radiance for the split-sum approximation and exact
cosine-convolved irradiance. The mapping (+Z up, Mitsuba's equirectangular convention) is
``latlong.py``; the filtering, ``mip.py``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from voxnero.render.latlong import (
    dir_to_theta_phi,
    envmap_lookup,
    pixel_dirs,
    pixel_solid_angles,
    rotate_dirs,
    row_edges,
)
from voxnero.render.microfacet import roughness_to_alpha
from voxnero.render.mip import lookup_levels, mip_chain, resample_area, roughness_to_level
from voxnero.render.sampling import sample_ggx_vndf
from voxnero.render.splitsum import hammersley


def luminance(rgb: Tensor) -> Tensor:
    """Rec. 709 luminance of linear RGB: (..., 3) -> (...)."""
    return rgb[..., 0] * 0.2126 + rgb[..., 1] * 0.7152 + rgb[..., 2] * 0.0722


IRRADIANCE_SOURCE_ROWS = 64
"""Maps taller than this are area-downsampled to it before the convolution (a cosine lobe is
smooth: 2.8 degrees between nodes, looked up bilinearly, suffices)."""
_KERNELS: dict[tuple, Tensor] = {}


def irradiance_table(img: Tensor) -> Tensor:
    """Exact cosine convolution of an equirectangular map, tabulated at its pixel centres.

    E(n) = sum over the texels l of L(l) * max(n . l, 0) * solid angle(l), for n at the pixel
    centres of the map (or of its area-downsampled copy of ``IRRADIANCE_SOURCE_ROWS`` rows, which
    keeps the integral); look it up with ``latlong.envmap_lookup``. For a row of normals and a
    row of texels the cosine depends only on their azimuth difference, so each pair of rows is
    a circular convolution along the columns, done by FFT: O(H^2 W log W), not O(H^2 W^2).
    Unlike an order-2 SH projection it does not ring: a sun lights no face turned away from it
    (order 2 gives a face at 90 degrees 9 % of the sun's normal irradiance). Differentiable
    w.r.t. ``img``; the kernel spectra are cached per size, device and dtype.

    Args:
        img: ``(H, 2H, C)`` linear radiance, +Z up (``latlong`` convention).

    Returns:
        ``(h, 2h, C)`` irradiance (radiance x sr), ``h = min(H, IRRADIANCE_SOURCE_ROWS)``; diffuse
        outgoing radiance is albedo / pi * E.
    """
    src = img
    if img.shape[0] > IRRADIANCE_SOURCE_ROWS:
        src = resample_area(img, IRRADIANCE_SOURCE_ROWS, 2 * IRRADIANCE_SOURCE_ROWS)
    H, W, C = src.shape
    key = (H, W, str(img.device), img.dtype)
    if key not in _KERNELS:
        kw = dict(device=img.device, dtype=torch.float64)
        cos_t = pixel_dirs(H, W, **kw)[:, 0, 2]                       # (H,) cos(theta) per row
        sin_t = (1.0 - cos_t * cos_t).clamp_min(0.0).sqrt()
        om = pixel_solid_angles(H, W, **kw)[:, 0]                     # (H,) texel solid angle
        dphi = torch.arange(W, **kw) * (2.0 * math.pi / W)            # column offsets
        k = (cos_t[:, None, None] * cos_t[None, :, None]
             + sin_t[:, None, None] * sin_t[None, :, None] * torch.cos(dphi)).clamp_min(0.0)
        # even in the offset, so its spectrum is real: (H normals, H texels, W // 2 + 1), kept
        # in the complex dtype of the map's spectrum so that no step converts it again
        spec_dtype = torch.fft.rfft(torch.zeros(2, dtype=img.dtype)).dtype
        _KERNELS[key] = torch.fft.rfft(k * om[None, :, None], dim=-1).real.to(spec_dtype)
    spec = torch.fft.rfft(src, dim=1)                                 # (H, W//2+1, C)
    out = torch.einsum("ihk,hkc->ikc", _KERNELS[key], spec)
    return torch.fft.irfft(out, n=W, dim=1)


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
            "cos_edges": torch.cos(row_edges(H, device=self.device)),
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
        """Cosine-convolved irradiance E(n) = integral L(l) max(n.l, 0) dl (``irradiance_table``:
        exact convolution of a 64 x 128 area-downsampled copy, tabulated at its pixel centres and
        looked up bilinearly).

        Args:
            n: (..., 3) world unit normals.

        Returns:
            (..., 3) irradiance; diffuse outgoing radiance is albedo / pi * E.
        """
        if self._irr is None:
            self._irr = irradiance_table(self.img.double()).float()
        return envmap_lookup(self._irr, self._to_map(n))
