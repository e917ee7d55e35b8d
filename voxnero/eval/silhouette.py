"""Scoring a mesh of a real capture that has no ground-truth mesh: object masks only.

The protocol (the DTU/NeuS practice, turned into silhouettes):

1. **Cull** (:func:`cull_by_masks`): a reconstruction of a real capture also holds the table,
   the backdrop and whatever else lies in the region of interest. A vertex is kept if it
   projects inside the mask of **every training view that sees it** (in front of the camera and
   inside the image), masks dilated by ``dilate_px`` pixels (2) so that a true surface point is
   not lost to a mask boundary that is a pixel off. Faces keep all three vertices.
2. **Silhouettes** (:func:`silhouettes`): the culled mesh is ray-cast through every pixel centre
   of the held-out views; a pixel is "object" when its ray hits the mesh.
3. **Scores** (:func:`silhouette_scores`): IoU, precision ``|P ∩ G| / |P|`` and recall
   ``|P ∩ G| / |G|`` of the predicted silhouettes ``P`` against the held-out masks ``G``
   (coverage ≥ 0.5), pooled over all pixels of all held-out views, and per view.

Held-out PSNR inside the masks is :func:`voxnero.eval.images.psnr` with the mask; renders are
made by whoever has a renderer (:mod:`voxnero.eval.capture`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import open3d as o3d

from voxnero.eval.views import MeshCaster, as_numpy, iter_view_rays

if TYPE_CHECKING:
    from voxnero.cameras.cameras import Cameras

DILATE_PX = 2
"""Dilation of the training masks for the culling, in pixels."""


def disk_dilate(mask: np.ndarray, px: int) -> np.ndarray:
    """Dilate boolean masks ``(..., H, W)`` by a disk of radius ``px`` pixels (0: unchanged)."""
    from scipy.ndimage import binary_dilation

    mask = np.asarray(mask, dtype=bool)
    if px <= 0:
        return mask.copy()
    r = np.arange(-px, px + 1)
    disk = (r[:, None] ** 2 + r[None, :] ** 2) <= px * px
    struct = disk.reshape((1,) * (mask.ndim - 2) + disk.shape)
    return binary_dilation(mask, structure=struct)


def project(points: np.ndarray, cameras: Cameras, index: int) -> tuple[np.ndarray, np.ndarray]:
    """Project world points into one OpenCV view.

    Args:
        points: ``(P, 3)`` points in the cameras' frame.
        cameras: the cameras.
        index: the view.

    Returns:
        ``uv (P, 2)`` continuous pixel coordinates (pixel (i, j) covers [i, i+1] × [j, j+1]) and
        ``z (P,)`` depth along the camera's +z.
    """
    c2w = as_numpy(cameras.c2w[index])
    K = as_numpy(cameras.K[index])
    pc = (np.asarray(points, np.float64) - c2w[:3, 3]) @ c2w[:3, :3]  # R^T (p - o)
    z = pc[:, 2]
    zs = np.where(np.abs(z) > 1e-12, z, 1e-12)
    uvw = pc @ K.T
    return uvw[:, :2] / zs[:, None], z


def cull_by_masks(points: np.ndarray, cameras: Cameras, masks, dilate_px: int = DILATE_PX
                  ) -> tuple[np.ndarray, dict]:
    """Which points lie inside the (dilated) mask of every view that sees them.

    Args:
        points: ``(P, 3)`` points (mesh vertices) in the cameras' frame.
        cameras: N training cameras.
        masks: ``(N, H, W)`` coverage (≥ 0.5 = object) or booleans.
        dilate_px: dilation of the masks in pixels.

    Returns:
        ``keep (P,)`` bool, and a record ``{"views": N, "dilate_px", "unseen": points no view
        sees (kept)}``.
    """
    m = as_numpy(masks) >= 0.5
    m = disk_dilate(m, dilate_px)
    n, h, w = m.shape
    keep = np.ones(len(points), dtype=bool)
    seen_any = np.zeros(len(points), dtype=bool)
    for i in range(n):
        uv, z = project(points, cameras, i)
        col, row = np.floor(uv[:, 0]).astype(np.int64), np.floor(uv[:, 1]).astype(np.int64)
        seen = (z > 0) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
        inside = np.zeros(len(points), dtype=bool)
        inside[seen] = m[i, row[seen], col[seen]]
        keep &= ~seen | inside
        seen_any |= seen
    return keep, {"views": n, "dilate_px": int(dilate_px), "unseen": int((~seen_any).sum())}


def cull_mesh(mesh: o3d.geometry.TriangleMesh, keep: np.ndarray) -> o3d.geometry.TriangleMesh:
    """A copy of ``mesh`` without the vertices where ``keep`` is False (and their faces)."""
    out = o3d.geometry.TriangleMesh(mesh)
    out.remove_vertices_by_mask(~np.asarray(keep, dtype=bool))
    out.remove_unreferenced_vertices()
    return out


def silhouettes(mesh: o3d.geometry.TriangleMesh, cameras: Cameras) -> np.ndarray:
    """``(N, H, W)`` bool: pixels whose centre ray hits ``mesh`` (all False for an empty mesh)."""
    out = np.zeros((len(cameras), cameras.height, cameras.width), dtype=bool)
    if len(mesh.triangles) == 0:
        return out
    caster = MeshCaster(mesh)
    for i, o, d, _ in iter_view_rays(cameras):
        out[i] = np.isfinite(caster.cast(o, d)["t"])
    return out


def silhouette_scores(pred: np.ndarray, gt) -> dict:
    """IoU, precision and recall of predicted silhouettes against masks.

    Args:
        pred: ``(N, H, W)`` bool predicted silhouettes.
        gt: ``(N, H, W)`` coverage (≥ 0.5 = object) or bool masks.

    Returns:
        ``{"iou", "precision", "recall"}`` pooled over all pixels of all views (1.0 where both
        are empty), ``"per_view": {"iou": [...], ...}`` and the pixel counts.
    """
    p = np.asarray(pred, dtype=bool)
    g = as_numpy(gt) >= 0.5 if not np.asarray(gt).dtype == bool else np.asarray(gt)

    def scores(pp, gg):
        inter, union = int((pp & gg).sum()), int((pp | gg).sum())
        npred, ngt = int(pp.sum()), int(gg.sum())
        return (inter / union if union else 1.0, inter / npred if npred else float(ngt == 0),
                inter / ngt if ngt else float(npred == 0))

    iou, prec, rec = scores(p, g)
    per = [scores(p[i], g[i]) for i in range(len(p))]
    return {"iou": iou, "precision": prec, "recall": rec,
            "per_view": {"iou": [v[0] for v in per], "precision": [v[1] for v in per],
                         "recall": [v[2] for v in per]},
            "pixels": {"pred": int(p.sum()), "mask": int(g.sum()), "both": int((p & g).sum())}}
