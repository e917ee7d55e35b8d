"""Camera rays for pixel batches and whole images, and pixel sampling (random pixels, jittered
points inside every pixel for box-filtered renders).

Pixel coordinates are continuous ``(x = column, y = row)`` in the frame of ``K``: pixel
(column i, row j) covers ``[i, i+1] x [j, j+1]`` and its centre is ``(i + 0.5, j + 0.5)``.
Rays are returned in the world frame of the cameras (the unit frame inside a ``Scene``):
origins are the camera centres and directions are unit vectors. The camera-space direction of a
pixel is ``K^-1 (x, y, 1)`` (OpenCV: +z forward; the same as kornia's ``unproject_points``
at depth 1, written out so that no per-ray ``(3, 3)`` copy is needed), then rotated by
``c2w``. ``pixel_rays`` and ``image_rays`` compute the same thing (tested).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from voxnero.cameras.cameras import Cameras


def camera_dirs(K: torch.Tensor, pix: torch.Tensor) -> torch.Tensor:
    """Unnormalised camera-space ray directions ``K^-1 (x, y, 1)`` (z = 1).

    Args:
        K: ``(M, 3, 3)`` or ``(3, 3)`` intrinsics in pixels (skew allowed).
        pix: ``(M, 2)`` continuous pixel coordinates (column, row).

    Returns:
        ``(M, 3)`` directions in OpenCV camera axes with z = 1.
    """
    if K.ndim == 2:
        K = K[None]
    fx, fy, cx, cy, skew = K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2], K[:, 0, 1]
    y = (pix[:, 1] - cy) / fy
    x = (pix[:, 0] - cx - skew * y) / fx
    return torch.stack([x, y, torch.ones_like(x)], dim=-1)


def pixel_rays(cameras: Cameras, cam_idx: torch.Tensor, pix: torch.Tensor
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays through given pixel positions of given cameras.

    Args:
        cameras: the cameras (OpenCV convention).
        cam_idx: ``(M,)`` long camera indices.
        pix: ``(M, 2)`` float continuous pixel coordinates ``[x = column, y = row]``; pixel
            centres are at ``+0.5``.

    Returns:
        ``origins (M, 3)`` camera centres and ``dirs (M, 3)`` unit directions, world frame.
    """
    dev = cameras.device
    cam_idx = cam_idx.to(dev).long()
    pix = pix.to(dev, torch.float32)
    d_cam = camera_dirs(cameras.K[cam_idx], pix)
    c2w = cameras.c2w[cam_idx]
    dirs = torch.einsum("mij,mj->mi", c2w[:, :3, :3], d_cam)
    return c2w[:, :3, 3], torch.nn.functional.normalize(dirs, dim=-1)


def pixel_samples(height: int, width: int, spp: int, generator: torch.Generator | None = None,
                  window: tuple[int, int, int, int] | None = None) -> Tensor:
    """Stratified jittered sample positions in every pixel.

    With ``spp = k²`` each pixel is split into a k × k grid with one uniform point per cell;
    otherwise ``spp`` independent uniform points.

    Args:
        height, width: image size.
        spp: samples per pixel.
        generator: random stream.
        window: (row0, col0, rows, cols) sub-image to sample (default the whole image).

    Returns:
        (rows, cols, spp, 2) continuous pixel coordinates (x = column, y = row); pixel (i, j)
        covers [i, i+1] × [j, j+1].
    """
    r0, c0, h, w = window if window is not None else (0, 0, height, width)
    k = int(round(math.sqrt(spp)))
    u = torch.rand(h, w, spp, 2, generator=generator)
    if k * k == spp:
        g = torch.arange(k, dtype=torch.float32)
        gy, gx = torch.meshgrid(g, g, indexing="ij")
        cell = torch.stack([gx.reshape(-1), gy.reshape(-1)], -1)  # (spp, 2)
        u = (cell + u) / k
    jj = torch.arange(r0, r0 + h, dtype=torch.float32)[:, None, None]
    ii = torch.arange(c0, c0 + w, dtype=torch.float32)[None, :, None]
    return torch.stack([ii + u[..., 0], jj + u[..., 1]], -1)


def pixel_centers(height: int, width: int, downscale: int = 1,
                  device: torch.device | str | None = None) -> torch.Tensor:
    """Continuous coordinates of the pixel centres of an image, optionally downscaled.

    With ``downscale = s`` the image is divided into ``s x s`` blocks (the last partial
    row/column of blocks is dropped) and the centre of each block is returned, i.e. pixel
    ``(i, j)`` of the ``(height // s, width // s)`` image is at ``((i + 0.5) s, (j + 0.5) s)``
    in the full-resolution frame of ``K``.

    Returns:
        ``(height // s, width // s, 2)`` float32 ``[x = column, y = row]``.
    """
    s = int(downscale)
    if s < 1:
        raise ValueError("downscale must be >= 1")
    xs = (torch.arange(width // s, device=device, dtype=torch.float32) + 0.5) * s
    ys = (torch.arange(height // s, device=device, dtype=torch.float32) + 0.5) * s
    yy, xx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([xx, yy], dim=-1)


def image_rays(cameras: Cameras, index: int, downscale: int = 1
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """Rays through every pixel centre of one camera's image.

    Args:
        cameras: the cameras.
        index: which camera.
        downscale: integer factor; rays go through the centres of ``s x s`` pixel blocks (see
            :func:`pixel_centers`).

    Returns:
        ``origins (H', W', 3)`` and ``dirs (H', W', 3)`` (unit), world frame, with
        ``H' = height // downscale`` and ``W' = width // downscale``; row 0 is the top row.
    """
    pix = pixel_centers(cameras.height, cameras.width, downscale, cameras.device)
    h, w = pix.shape[:2]
    c2w = cameras.c2w[int(index)]
    d = camera_dirs(cameras.K[int(index)], pix.reshape(-1, 2)) @ c2w[:3, :3].T
    d = torch.nn.functional.normalize(d, dim=-1).reshape(h, w, 3)
    return c2w[:3, 3].expand(h, w, 3).clone(), d


def random_pixels(n: int, n_cams: int, height: int, width: int,
                  generator: torch.Generator | None = None, jitter: bool = False,
                  device: torch.device | str | None = None
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """Draw ``n`` pixels uniformly over all cameras and pixels (with replacement).

    Args:
        n: number of samples.
        n_cams: number of cameras to draw from.
        height: image height.
        width: image width.
        generator: optional torch generator (reproducible draws); its device is used when
            ``device`` is not given.
        jitter: if False, return pixel centres ``(i + 0.5, j + 0.5)``; if True, a uniform point
            inside the pixel ``(i + U, j + U')``, ``U, U' ~ U[0, 1)``.
        device: device of the results.

    Returns:
        ``cam_idx (n,)`` long, ``pix (n, 2)`` float32 ``[x = column, y = row]``. The integer
        pixel is ``pix.floor().long()`` in both modes.
    """
    if device is None:
        device = generator.device if generator is not None else "cpu"
    kw = dict(generator=generator, device=device)
    cam = torch.randint(0, n_cams, (n,), dtype=torch.long, **kw)
    flat = torch.randint(0, height * width, (n,), dtype=torch.long, **kw)
    ij = torch.stack([flat % width, flat // width], dim=-1).to(torch.float32)
    if jitter:
        off = torch.rand((n, 2), dtype=torch.float32, **kw)
    else:
        off = torch.full((n, 2), 0.5, dtype=torch.float32, device=device)
    return cam, ij + off
