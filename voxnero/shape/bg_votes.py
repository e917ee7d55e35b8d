"""Which pixels of the photos the background explains, and how often a point is seen against it.

A mask-free visual hull: a pixel whose photo matches the scene's background (the learnable
env map, or the known colour of images with alpha) along its ray most likely sees past the
object, so a point that projects onto such pixels in many of the views that see it is free
space; a point of the object projects inside its outline in every view. The pixel test errs
on the object's side (a reflection can match the map it reflects), so the ratio is used
against a threshold measured on the object itself (:func:`voxnero.shape.hull.grow_seen_as_object`).

Unit frame, linear radiance, cameras in the OpenCV convention (:class:`~voxnero.cameras.
cameras.Cameras`); masks are ``(V, H, W)`` indexed ``[view, row, column]``.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from voxnero.cameras.cameras import Cameras
from voxnero.cameras.rays import image_rays

TOL_ABS = 0.03
"""Largest linear difference (any channel) of a background pixel from the drawn background,
plus :data:`TOL_REL` of the background's brightest channel (gear_brass: 80 % of the true
background pixels pass, 7.5 % of the object's)."""
TOL_REL = 0.1


@torch.no_grad()
def background_pixels(cams: Cameras, photos: torch.Tensor,
                      background: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
                      tol_abs: float = TOL_ABS, tol_rel: float = TOL_REL) -> torch.Tensor:
    """``(V, H, W)`` bool: the pixels whose photo the background explains.

    Args:
        cams: the ``V`` cameras of the photos.
        photos: ``(V, H, W, 3)`` linear radiance.
        background: ``background(origins, dirs)`` → ``(n, 3)`` linear radiance behind the
            object along unit-frame rays.
        tol_abs, tol_rel: a pixel passes when every channel is within
            ``tol_abs + tol_rel · max(background)`` of the background.
    """
    v, h, w = photos.shape[:3]
    out = torch.empty(v, h * w, dtype=torch.bool, device=photos.device)
    for c in range(v):
        o, d = image_rays(cams, c)
        bg = background(o.reshape(-1, 3), d.reshape(-1, 3))
        err = (photos[c].reshape(-1, 3) - bg).abs().amax(-1)
        out[c] = err < tol_abs + tol_rel * bg.amax(-1)
    return out.view(v, h, w)


@torch.no_grad()
def background_ratio(cams: Cameras, masks: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``(K,)`` for each point, the fraction of the views it projects into (in front of the
    camera, inside the image) in which its pixel is a background pixel; 1 where no view sees it.

    Args:
        cams: the ``V`` cameras.
        masks: ``(V, H, W)`` bool, :func:`background_pixels`.
        points: ``(K, 3)`` unit-frame points.
    """
    v, h, w = masks.shape
    votes = torch.zeros(points.shape[0], device=masks.device)
    seen = torch.zeros_like(votes)
    for c in range(v):
        uv, z = cams.project(points, c)
        u, r = uv[:, 0].floor().long(), uv[:, 1].floor().long()
        ok = (z > 0) & (u >= 0) & (u < w) & (r >= 0) & (r < h)
        seen += ok.float()
        votes[ok] += masks[c, r[ok], u[ok]].float()
    return torch.where(seen > 0, votes / seen.clamp_min(1.0), torch.ones_like(votes))
