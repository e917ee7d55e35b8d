"""Ground-truth per-pixel maps of analytic scenes: coverage, normals, depth and materials.

Like the dev scenes (../shared/data/README.md, "Ground-truth maps"): from the primary rays of
the jittered pixel samples, coverage = fraction of samples that hit an object; every other map
is the average over the *covered* samples (normals renormalised), 0 on background. Depth is the
z-depth along the camera's viewing axis, ``dot(P − centre, forward)``.
"""

from __future__ import annotations

import torch

from voxnero.synth.materials import MaterialTable
from voxnero.synth.shapes import Union

N_FEATURES = 10
"""Columns of :func:`aov_samples`: count, normal (3), depth, albedo (3), metallic, roughness."""


def aov_samples(geometry: Union, materials: MaterialTable, o: torch.Tensor, d: torch.Tensor,
                t: torch.Tensor, obj: torch.Tensor, forward: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-sample ground-truth features of the primary rays that hit an object.

    Args:
        geometry: the scene's shapes.
        materials: one material per shape.
        o, d: (N, 3) primary rays (unit d).
        t: (N,) primary hit distance (``inf`` on a miss); obj: (N,) object index (−1 on a miss).
        forward: (N, 3) the viewing axis (OpenCV +z) of each ray's camera.

    Returns:
        (rows (K,) indices into the N rays that hit, features (K, N_FEATURES)).
    """
    k = torch.nonzero(obj >= 0).squeeze(1)
    x = o[k] + t[k, None] * d[k]
    albedo, metallic, rough = materials.gather(obj[k])
    feats = torch.cat([torch.ones_like(t[k, None]), geometry.normal(x, obj[k]),
                       ((x - o[k]) * forward[k]).sum(-1, keepdim=True), albedo, metallic,
                       rough], -1)
    return k, feats


def finish_aov(acc: torch.Tensor, spp: int) -> dict[str, torch.Tensor]:
    """Per-pixel maps from summed features ``acc`` (P, N_FEATURES) of ``spp`` samples/pixel.

    Returns:
        dict of (P, ...) float32: ``coverage`` in [0, 1], ``normal`` (P, 3) world unit outward
        normals, ``depth`` z-depth, ``albedo`` (P, 3) linear, ``metallic``, ``roughness``
        (perceptual r); all 0 where nothing was hit.
    """
    cnt = acc[:, :1]
    mean = acc[:, 1:] / cnt.clamp_min(1)
    normal = torch.nn.functional.normalize(mean[:, 0:3], dim=-1)
    return {"coverage": (cnt[:, 0] / spp).float(), "normal": normal.float(),
            "depth": mean[:, 3].float(), "albedo": mean[:, 4:7].float(),
            "metallic": mean[:, 7].float(), "roughness": mean[:, 8].float()}
