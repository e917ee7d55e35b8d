"""Image metrics: PSNR, SSIM (kornia), per-channel scale fit, MAE.

Images are channels-last, ``(H, W, C)`` or ``(N, H, W, C)``, numpy or torch, and — unless a
caller says otherwise — **sRGB-encoded values in [0, 1]** (what a viewer shows; convert linear
renders with :func:`voxnero.io.color.linear_to_srgb` first). Masks are ``(H, W)`` or
``(N, H, W)``, bool or numeric; pixels with ``mask > 0.5`` count. Metrics pool every selected
pixel and channel of the batch (average per-view values yourself if you want the mean of views).
"""

from __future__ import annotations

import math

import kornia
import numpy as np
import torch


def _t(x: torch.Tensor | np.ndarray) -> torch.Tensor:
    """float64 CPU tensor, channels-last with a batch dimension: ``(N, H, W, C)``."""
    t = x.detach().to("cpu", torch.float64) if isinstance(x, torch.Tensor) \
        else torch.as_tensor(np.asarray(x, dtype=np.float64))
    if t.ndim == 2:
        t = t[..., None]
    if t.ndim == 3:
        t = t[None]
    if t.ndim != 4:
        raise ValueError(f"images must be (H, W[, C]) or (N, H, W, C), got {tuple(t.shape)}")
    return t


def _mask(mask, like: torch.Tensor) -> torch.Tensor:
    """Boolean ``(N, H, W, 1)`` selection broadcastable to ``like (N, H, W, C)``."""
    if mask is None:
        return torch.ones(like.shape[:3] + (1,), dtype=torch.bool)
    m = mask.detach().cpu() if isinstance(mask, torch.Tensor) else torch.as_tensor(np.asarray(mask))
    m = m.to(torch.float64) > 0.5
    if m.ndim == 2:
        m = m[None]
    if m.ndim == 4 and m.shape[-1] == 1:
        m = m[..., 0]
    if m.shape != like.shape[:3]:
        raise ValueError(f"mask {tuple(m.shape)} does not match images {tuple(like.shape[:3])}")
    return m[..., None]


def _pair(pred, gt) -> tuple[torch.Tensor, torch.Tensor]:
    p, g = _t(pred), _t(gt)
    if p.shape != g.shape:
        raise ValueError(f"pred {tuple(p.shape)} and gt {tuple(g.shape)} differ in shape")
    return p, g


def mse(pred, gt, mask=None) -> float:
    """Mean squared error over the selected pixels and all channels."""
    p, g = _pair(pred, gt)
    m = _mask(mask, p).expand_as(p)
    if not m.any():
        raise ValueError("the mask selects no pixel")
    return float(((p - g)[m] ** 2).mean())


def psnr(pred, gt, mask=None, max_val: float = 1.0) -> float:
    """Peak signal-to-noise ratio ``10 log10(max_val² / MSE)`` in dB.

    Args:
        pred, gt: images (module docstring), sRGB in [0, 1] unless stated.
        mask: optional selection of pixels.
        max_val: peak value (1 for [0, 1] images).

    Returns:
        PSNR in dB; ``math.inf`` for identical images (not capped: cap when averaging, e.g.
        ``min(p, 100)``; JSON reports write it as the string ``"inf"``).
    """
    e = mse(pred, gt, mask)
    return math.inf if e == 0 else 10.0 * math.log10(max_val**2 / e)


def ssim_map(pred, gt, window_size: int = 11, max_val: float = 1.0,
             padding: str = "same") -> torch.Tensor:
    """Per-pixel SSIM (kornia: Gaussian window ``window_size``, σ = 1.5).

    Args:
        padding: ``"same"`` (map of the image's size) or ``"valid"`` (only windows inside the
            image, ``window_size − 1`` pixels smaller).

    Returns:
        ``(N, H', W')`` SSIM averaged over channels.
    """
    p, g = _pair(pred, gt)
    s = kornia.metrics.ssim(p.permute(0, 3, 1, 2), g.permute(0, 3, 1, 2), window_size,
                            max_val=max_val, padding=padding)
    return s.mean(1)


def ssim(pred, gt, mask=None, window_size: int = 11, max_val: float = 1.0) -> float:
    """Mean structural similarity (1 for identical images).

    Args:
        pred, gt: images (module docstring), sRGB in [0, 1] unless stated.
        mask: optional; the SSIM map (computed on the whole image) is averaged over it.
        window_size: Gaussian window size (σ = 1.5, as in Wang et al. 2004).
        max_val: dynamic range.
    """
    s = ssim_map(pred, gt, window_size, max_val)
    m = _mask(mask, _t(pred))[..., 0]
    if not m.any():
        raise ValueError("the mask selects no pixel")
    return float(s[m].mean())


def fit_channel_scale(pred, gt, mask=None, clip: float | None = None
                      ) -> torch.Tensor | np.ndarray:
    """Least-squares per-channel scale ``s_c = argmin Σ (s·pred_c − gt_c)²`` over the mask.

    Resolves the albedo–light (relighting) scale ambiguity: compare ``s · pred`` with ``gt``.
    Fit on linear values if the metric that follows is computed after scaling linear images.

    Args:
        pred, gt: images (linear values for a relighting comparison).
        mask: optional selection of pixels.
        clip: the level both images are clipped at before they are compared (8-bit photos:
            1), or None. Then the scale minimises ``Σ (min(s·pred_c, clip) − gt_c)²`` over the
            selected pixel-channels whose target is below ``0.99 · clip`` (exactly: the error
            is quadratic in s between the scales at which successive pixels clip). A pixel the
            scaled render clips bounds the scale but does not measure it; without this a few
            HDR highlights (a sun's glint at 10-100× the clip level, a Monte Carlo firefly)
            dominate the sum and scale the whole image dark.

    Returns:
        ``(C,)`` scales (numpy if ``pred`` is numpy, else a float32 torch tensor); 1 for a
        channel whose prediction is all zero there.
    """
    p, g = _pair(pred, gt)
    m = _mask(mask, p).expand_as(p)
    if clip is None:
        w = m.to(torch.float64)
        num, den = (w * p * g).sum((0, 1, 2)), (w * p * p).sum((0, 1, 2))
        s = torch.where(den > 0, num / torch.where(den > 0, den, 1.0), torch.ones_like(den))
    else:
        m = m & (g < 0.99 * clip)
        s = torch.stack([_clipped_scale(p[..., c][m[..., c]], g[..., c][m[..., c]], clip)
                         for c in range(p.shape[-1])])
    return s.float() if isinstance(pred, torch.Tensor) else s.numpy()


def _clipped_scale(p: torch.Tensor, g: torch.Tensor, clip: float) -> torch.Tensor:
    """argmin over s ≥ 0 of ``Σ (min(s·p, clip) − g)²`` for ``(N,)`` values; 1 if no p > 0.

    Pixel i clips from ``t_i = clip / p_i``. Sorted by t, for s between the k-th and the
    (k+1)-th of them the first k are clipped (a constant ``(clip − g)²`` each) and the rest are
    quadratic in s, so each interval's minimum is its least-squares scale clamped to the
    interval; suffix sums give all intervals at once. (Refitting on the unclipped pixels until
    they stop changing is not enough: from the plain least-squares scale, glints at 500× leave
    it stuck near 1/500, where they are not clipped.)
    """
    keep = p > 0  # a black pixel adds the same (0 − g)² at every scale
    if not bool(keep.any()):
        return torch.ones((), dtype=torch.float64)
    p, g = p[keep], g[keep]
    t = clip / p
    order = torch.argsort(t)
    p, g, t = p[order], g[order], t[order]

    def suffix(x: torch.Tensor) -> torch.Tensor:  # (N + 1,): sum of x[k:] for k = 0..N
        return torch.cat([torch.flip(torch.cumsum(torch.flip(x, [0]), 0), [0]), x.new_zeros(1)])

    a, b, c = suffix(p * p), suffix(p * g), suffix(g * g)
    d = torch.cat([g.new_zeros(1), torch.cumsum((clip - g) ** 2, 0)])  # the k clipped ones
    lo = torch.cat([g.new_zeros(1), t])                                  # interval k: [lo, hi]
    hi = torch.cat([t, torch.full_like(g[:1], math.inf)])
    s = torch.where(a > 0, b / a.clamp_min(1e-300), lo)
    s = torch.minimum(torch.maximum(s, lo), hi)
    err = a * s * s - 2 * b * s + c + d
    return s[torch.argmin(err)]


def mae(a, b, mask=None) -> float:
    """Mean absolute error over the selected pixels and all channels (e.g. roughness maps)."""
    p, g = _pair(a, b)
    m = _mask(mask, p).expand_as(p)
    if not m.any():
        raise ValueError("the mask selects no pixel")
    return float((p - g)[m].abs().mean())
