"""Filtering of equirectangular maps: solid-angle-weighted area resampling, the mip chain and
roughness-filtered lookups (differentiable, for learnable maps). Pixel cells and the mapping are
those of ``latlong.py``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from voxnero.render.latlong import bilinear, dir_to_uv, row_edges
from voxnero.render.microfacet import roughness_to_alpha


def _theta_overlap(h_coarse: int, h_fine: int, device=None) -> Tensor:
    """(Hc, Hf) row weights: solid angle of the overlap of coarse and fine row cells."""
    ec = row_edges(h_coarse, device=device)
    ef = row_edges(h_fine, device=device)
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
        out = out.index_add(0, sel, w[sel, None].to(out.dtype) * bilinear(img, uv[sel]))
    return out.reshape(*lead, -1)
