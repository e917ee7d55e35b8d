"""Is the background of a capture at infinity? A measurement on the photos, before training.

A background at infinity gives one radiance per direction, whatever the camera: two pixels of
different views whose rays leave the region of interest (the unit sphere) in the same direction
show the same colour. A near background (a table, a room) does not: the same direction from two
camera positions meets different points. So the photos' background pixels are binned by
direction on an equirectangular grid (``bins_w`` × ``bins_w / 2``; by default a bin spans
:data:`BIN_PIXELS` sampled pixels, so that a view's bin mean averages a few pixels), each
(view, bin) is averaged, each bin's environment colour is the mean over the views that see it,
and the evidence is how well that best "environment map" explains the pixels:

* ``env_fit_psnr``: PSNR (sRGB) of every background pixel of a bin seen by two or more views
  against the bin's environment colour: what any direction-only model (the env map) can reach
  at this angular resolution;
* ``view_fit_psnr``: the same against the pixel's own view's bin mean: the floor set by
  texture inside a bin (no parallax involved);
* ``parallax_db`` = ``view_fit_psnr − env_fit_psnr``: what the views disagree beyond texture.

Only pixels whose rays miss the unit sphere count (the object and whatever the region of
interest holds are modelled by the SDF).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

BIN_PIXELS = 4
"""Sampled pixels (at the median focal length) across one direction bin."""


def background_rays(split, radius: float = 1.0, stride: int = 2
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Background pixels of a split: rays that miss the sphere of ``radius``.

    Args:
        split: a :class:`voxnero.data.scene.Split` (unit frame, linear images).
        radius: region of interest (unit frame).
        stride: keep every ``stride``-th pixel in each image axis.

    Returns:
        ``view (P,)`` index, ``dirs (P, 3)`` unit world directions, ``srgb (P, 3)`` colours.
    """
    from voxnero.cameras.rays import image_rays
    from voxnero.io.color import linear_to_srgb

    views, dirs, cols = [], [], []
    for i in range(split.images.shape[0]):
        o, d = image_rays(split.cameras, i)
        o, d = o[::stride, ::stride].reshape(-1, 3), d[::stride, ::stride].reshape(-1, 3)
        b = (o * d).sum(-1)
        miss = ((o * o).sum(-1) - b * b > radius * radius) | (b > 0)  # closest approach / behind
        c = linear_to_srgb(split.images[i, ::stride, ::stride].reshape(-1, 3).clamp(0, 1))
        views.append(torch.full((int(miss.sum()),), i))
        dirs.append(d[miss])
        cols.append(c[miss])
    return (torch.cat(views).numpy(), torch.cat(dirs).double().numpy(),
            torch.cat(cols).double().numpy())


def distant_background_evidence(split, radius: float = 1.0, bins_w: int | None = None,
                                stride: int = 2) -> dict[str, Any]:
    """The numbers of the module docstring for one split.

    ``bins_w`` (bins around the horizon) defaults to ``2π / (BIN_PIXELS · stride / f)`` with
    ``f`` the median focal length in pixels.

    Returns:
        ``{"env_fit_psnr", "view_fit_psnr", "parallax_db", "background_pixels" (sampled),
        "shared_fraction" (of those in bins seen by ≥ 2 views), "bins_w", "stride"}``;
        PSNRs are None when no bin is shared by two views.
    """
    if bins_w is None:
        f = float(split.cameras.K[:, 0, 0].median())
        bins_w = max(8, int(round(2 * math.pi / (BIN_PIXELS * stride / f))))
    view, d, col = background_rays(split, radius, stride)
    out: dict[str, Any] = {"background_pixels": int(len(view)), "bins_w": bins_w,
                           "stride": stride, "radius": radius}
    if len(view) == 0:
        return {**out, "env_fit_psnr": None, "view_fit_psnr": None, "parallax_db": None,
                "shared_fraction": 0.0}
    bins_h = bins_w // 2
    u = (np.arctan2(d[:, 0], d[:, 1]) / (2 * math.pi)) % 1.0
    v = np.arccos(np.clip(d[:, 2], -1, 1)) / math.pi
    b = (np.minimum((v * bins_h).astype(np.int64), bins_h - 1) * bins_w
         + np.minimum((u * bins_w).astype(np.int64), bins_w - 1))
    # per (view, bin) means
    key = view.astype(np.int64) * (bins_w * bins_h) + b
    ukey, inv = np.unique(key, return_inverse=True)
    cnt = np.bincount(inv)
    vb_mean = np.stack([np.bincount(inv, col[:, c]) for c in range(3)], -1) / cnt[:, None]
    # per bin: mean over the views that see it (each view once)
    ubin = ukey % (bins_w * bins_h)
    bkey, binv = np.unique(ubin, return_inverse=True)
    nviews = np.bincount(binv)
    env = np.stack([np.bincount(binv, vb_mean[:, c]) for c in range(3)], -1) / nviews[:, None]
    shared = nviews[binv][inv] >= 2  # per pixel
    out["shared_fraction"] = float(shared.mean())
    if not shared.any():
        return {**out, "env_fit_psnr": None, "view_fit_psnr": None, "parallax_db": None}
    e_env = float(((col - env[binv][inv]) ** 2)[shared].mean())
    e_view = float(((col - vb_mean[inv]) ** 2)[shared].mean())

    def db(e: float) -> float:
        return 10.0 * math.log10(1.0 / max(e, 1e-12))

    out.update(env_fit_psnr=round(db(e_env), 3), view_fit_psnr=round(db(e_view), 3),
               parallax_db=round(db(e_view) - db(e_env), 3))
    return out
