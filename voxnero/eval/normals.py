"""Normal error of a mesh at test views (mean / median angle in degrees).

The predicted normal at a pixel is the mesh's **interpolated vertex normal** at the first hit of
the ray through the pixel centre (barycentric interpolation, renormalised): a smooth shading
normal, like the ground truth's (shading normals of the rendered geometry). ``source="face"``
uses the geometric normal of the hit triangle instead. Normals are compared as oriented
directions, so a mesh with flipped winding scores near 180°.

Only pixels fully covered in the GT mask (``mask == 255``) with a non-zero GT normal count; of
those, pixels where the predicted mesh is missed are excluded from the angles and reported as
``1 − hit_fraction``. Directions are frame-independent under the project's normalisation
(translation + uniform scale), so any frame works as long as mesh and cameras share it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
import open3d as o3d
import torch

from voxnero.eval.views import (
    MeshCaster,
    RayList,
    as_numpy,
    full_coverage,
    iter_view_rays,
    view_rays,
)

if TYPE_CHECKING:
    from voxnero.cameras.cameras import Cameras


def load_gt_normals(scene_root: str | Path, split: str, names: list[str]) -> np.ndarray | None:
    """Ground-truth normal maps of a dev/synth scene: ``gt/<split>_normal/<name>.exr``.

    Args:
        scene_root: scene folder.
        split: split name (``"test"``).
        names: image names (file stems) in the split's order.

    Returns:
        ``(V, H, W, 3)`` float32 world-space unit normals (0 on background), or None when the
        scene has no such folder. World space is the input frame; directions do not change
        under the project's normalisation (translation + uniform scale).
    """
    from voxnero.io.exr import read_exr

    folder = Path(scene_root) / "gt" / f"{split}_normal"
    if not folder.is_dir():
        return None
    return np.stack([read_exr(folder / f"{n}.exr")[..., :3] for n in names])


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle in degrees between directions ``a (..., 3)`` and ``b (..., 3)`` (any lengths > 0)."""
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    # atan2 of |a×b| and a·b is accurate at small and large angles, unlike arccos
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1),
                                 np.einsum("...i,...i->...", a, b)))


def render_normals(caster: MeshCaster, cameras: Cameras, index: int,
                   source: Literal["vertex", "face"] = "vertex",
                   rays: tuple[np.ndarray, np.ndarray] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """World-space normal map of the mesh seen from one view.

    Args:
        caster: the mesh, ready to cast.
        cameras: cameras in the mesh's frame.
        index: the view.
        source: ``"vertex"`` (interpolated vertex normals) or ``"face"``.
        rays: optional precomputed ``(origins, dirs)`` ``(H, W, 3)`` of that view.

    Returns:
        ``normals (H, W, 3)`` unit (0 where missed) and ``hit (H, W)`` bool.
    """
    o, d = rays if rays is not None else view_rays(cameras, index)[:2]
    res = caster.cast(o, d)
    hit = np.isfinite(res["t"])
    n = np.zeros(o.shape, dtype=np.float64)
    if source == "vertex":
        n[hit] = caster.vertex_normal_at(res["tri"][hit], res["uv"][hit])
    elif source == "face":
        n[hit] = res["face_normal"][hit]
    else:
        raise ValueError(f"source must be 'vertex' or 'face', got {source!r}")
    return n, hit


def scored_pixels(gt: np.ndarray, full: np.ndarray) -> np.ndarray:
    """The pixels of one view whose normal error counts: fully covered in the GT mask and with a
    GT normal. ``gt (H, W, 3)``, ``full (H, W)`` bool (:func:`voxnero.eval.views.full_coverage`);
    returns ``(H, W)`` bool (the mesh must still be hit there)."""
    return full & (np.linalg.norm(gt, axis=-1) > 0.5)


def normal_error_at_views(mesh: o3d.geometry.TriangleMesh, cameras: Cameras,
                          gt_normals: torch.Tensor | np.ndarray,
                          masks: torch.Tensor | np.ndarray,
                          source: Literal["vertex", "face"] = "vertex",
                          rays: RayList | None = None) -> dict[str, float]:
    """Angular error between the mesh's normals and GT normal maps at test views.

    Args:
        mesh: legacy Open3D mesh with vertex normals, in the cameras' frame.
        cameras: ``V`` cameras (OpenCV c2w).
        gt_normals: ``(V, H, W, 3)`` world-space unit normals (0 on background).
        masks: ``(V, H, W)`` coverage (8-bit, 255 = full, or fractions in [0, 1]).
        source: ``"vertex"`` (interpolated vertex normals, default) or ``"face"``.
        rays: optional precomputed rays, ``list(iter_view_rays(cameras))``.

    Returns:
        dict ``mean_deg``, ``median_deg``, ``n_pixels`` (compared), ``hit_fraction`` (of the
        eligible GT pixels, the share where the mesh was hit). NaN angles if nothing compared.
    """
    gt = as_numpy(gt_normals)
    full = full_coverage(masks)
    if (gt.ndim != 4 or gt.shape[3] != 3 or gt.shape[:3] != full.shape
            or gt.shape[0] != len(cameras)):
        raise ValueError(f"gt_normals {gt.shape} must be (V, H, W, 3) matching masks "
                         f"{full.shape} and {len(cameras)} cameras")
    if source == "vertex" and not mesh.has_vertex_normals():
        mesh = o3d.geometry.TriangleMesh(mesh)
        mesh.compute_vertex_normals()
    caster = MeshCaster(mesh)
    angles, eligible = [], 0
    for v, o, d, _ in (rays if rays is not None else iter_view_rays(cameras)):
        pred, hit = render_normals(caster, cameras, v, source, rays=(o, d))
        ok = scored_pixels(gt[v], full[v])
        eligible += int(ok.sum())
        ok &= hit
        angles.append(angle_deg(pred[ok], gt[v][ok]))
    a = np.concatenate(angles)
    nan = float("nan")
    return {"mean_deg": float(a.mean()) if len(a) else nan,
            "median_deg": float(np.median(a)) if len(a) else nan,
            "n_pixels": int(len(a)),
            "hit_fraction": len(a) / eligible if eligible else nan}


def gt_edge_distance(gt: np.ndarray, valid: np.ndarray, edge_deg: float = 20.0) -> np.ndarray:
    """Distance in pixels from each pixel of one view to the nearest edge of its GT normal map.

    An edge pixel is one whose GT normal differs by more than ``edge_deg`` from its right or
    lower neighbour's (both pixels of such a pair count), or one outside ``valid``; so the
    outline is an edge on both its sides (the last valid pixel and the first one outside). The
    image border is no edge. Used to split the normal error into the band along the
    object's edges, where a grid's rounding of a corner by a voxel shows, and the faces.

    Args:
        gt: ``(H, W, 3)`` GT normals (any length > 0 where valid).
        valid: ``(H, W)`` bool, the pixels that carry a GT normal.
        edge_deg: angle between neighbours that makes an edge, degrees.

    Returns:
        ``(H, W)`` float64 Euclidean distance in pixels to the nearest edge pixel (0 on one).
    """
    from scipy import ndimage

    g = np.where(valid[..., None], gt, 1.0)  # any non-zero direction outside: no NaN angles
    edge = ~valid
    across = angle_deg(g[:, :-1], g[:, 1:]) > edge_deg
    edge[:, :-1] |= across
    edge[:, 1:] |= across
    down = angle_deg(g[:-1], g[1:]) > edge_deg
    edge[:-1] |= down
    edge[1:] |= down
    if not edge.any():
        return np.full(edge.shape, np.inf)
    return ndimage.distance_transform_edt(~edge)
