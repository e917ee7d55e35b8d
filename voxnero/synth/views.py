"""Render whole views: box-filtered radiance images and ground-truth maps of several cameras.

Rays of several views are traced together (in chunks of ``chunk`` rays) so that the per-call
overhead of the vectorised tracer is shared; every pixel averages ``spp`` paths through
jittered positions inside its footprint (box reconstruction filter, anti-aliased silhouettes),
and the same primary rays give the coverage masks and ground-truth maps.
"""

from __future__ import annotations

import torch

from voxnero.synth.aov import N_FEATURES, aov_samples, finish_aov
from voxnero.synth.materials import MaterialTable
from voxnero.synth.pathtrace import trace_paths
from voxnero.synth.shapes import Union


def render_views(geometry: Union, materials: MaterialTable, env, cameras,
                 indices: list[int], spp: int = 16, max_depth: int = 3,
                 generator: torch.Generator | None = None, chunk: int = 1 << 18
                 ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Radiance and ground-truth maps of cameras ``indices``.

    Args:
        geometry, materials, env, max_depth: as in :func:`voxnero.synth.pathtrace.trace_paths`.
        cameras: :class:`voxnero.cameras.cameras.Cameras` (OpenCV); rays come from
            :func:`voxnero.cameras.rays.pixel_rays` (pixel centre at +0.5).
        indices: which cameras (V of them).
        spp: paths per pixel (stratified jitter when a square number).
        generator: random generator (CPU) for jitter and path sampling.
        chunk: rays traced at once (bounds memory: about 1 KB per ray).

    Returns:
        (radiance (V, H, W, 3) float32 linear, maps) with maps as in
        :func:`voxnero.synth.aov.finish_aov`, each reshaped to (V, H, W, ...).
    """
    from voxnero.cameras.rays import pixel_rays, pixel_samples

    H, W = cameras.height, cameras.width
    V, P = len(indices), H * W
    pix = pixel_samples(H, W, spp, generator).reshape(-1, 2)
    pid = torch.arange(H * W).repeat_interleave(spp)
    n = pix.shape[0]
    dev = cameras.device
    rgb = torch.zeros(V * P, 3, device=dev)
    aov = torch.zeros(V * P, N_FEATURES, device=dev)
    forward_all = cameras.c2w[:, :3, 2]
    for s in range(0, V * n, chunk):
        flat = torch.arange(s, min(s + chunk, V * n))
        view, k = flat // n, flat % n
        cam = torch.as_tensor(indices, dtype=torch.long)[view]
        o, d = pixel_rays(cameras, cam, pix[k])
        L, t, obj = trace_paths(geometry, materials, env, o, d, max_depth, generator)
        rows = (view * P + pid[k]).to(dev)
        rgb.index_add_(0, rows, L.to(rgb.dtype))
        hit_rows, feats = aov_samples(geometry, materials, o, d, t, obj,
                                      forward_all[cam.to(dev)])
        aov.index_add_(0, rows[hit_rows], feats.to(aov.dtype))
    maps = {name: v.reshape(V, H, W, *v.shape[1:]) for name, v in finish_aov(aov, spp).items()}
    return (rgb / spp).reshape(V, H, W, 3), maps
