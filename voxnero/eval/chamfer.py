"""Chamfer distance by the project's protocol (NeRO's, see ``/work/shared/DESIGN.md``).

Protocol, fixed for every scene and method:

* **Ground-truth points**: test-view z-depth back-projected through the pixel centres,
  ``P = o + d · z / (d · forward)`` (``forward`` = the camera's viewing axis), only at pixels fully
  covered by the object (``mask == 255``) with a positive finite depth. Silhouette pixels are left
  out because their depth mixes object and background.
* **Predicted points**: the predicted mesh ray-cast (Open3D ``RaycastingScene``) at the same views
  through the same pixel centres, first hit. By default every hit counts except at the GT
  silhouette pixels (``0 < mask < 255``), so geometry where the truth shows background (floaters,
  a too-large shape) is penalised while the ambiguous ring is treated as for the truth
  (``pred_pixels="unambiguous"``). ``"mask"`` keeps only ``mask == 255`` pixels, ``"all"`` every
  hit.
* Both clouds are mapped to the scene's **input frame** (``norm.to_input``) and then
  voxel-downsampled at 0.01 (Open3D ``voxel_down_sample``: the centroid of the points in each
  occupied voxel).
* ``acc = mean d(pred → gt)``, ``comp = mean d(gt → pred)``, ``cd = (acc + comp) / 2``, with
  unsquared Euclidean nearest-neighbour distances (Open3D KD-tree).

**The stored depth is a pixel average.** The scenes' ``gt/test_depth`` (dev scenes and corpus
alike, rendered by Mitsuba with a box filter) averages the position over each pixel's covered
part. Where the object covers a pixel but its depth jumps inside it (a cavity's rim in front of
its floor, a rod in front of another), the back-projected point lies in mid-air between the two
surfaces. Such pixels are under 1 % of the full-coverage ones, but after the downsampling they
are points the truth does not have: the truth itself scores 0.1-0.4 px against them, and a lid
over a cavity finds them near (a filled bowl's lid lies 4 px from them and 60 px from the bowl's
floor). :func:`mesh_depth_at_views` gives the depth of the true mesh at the pixel centres instead;
``voxnero eval`` reports the Chamfer against it as ``chamfer_exact`` when the scene has
``gt/mesh.ply``.
"""

from __future__ import annotations

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
    partial_coverage,
)

if TYPE_CHECKING:
    from voxnero.cameras.cameras import Cameras
    from voxnero.data.scene import Normalisation

VOXEL = 0.01
"""Voxel size of the downsampling, in the input frame (dev scenes: object radius <= 0.9)."""


def _cloud(p: np.ndarray) -> o3d.geometry.PointCloud:
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(p)))


def downsample(points: np.ndarray, voxel: float | None = VOXEL) -> np.ndarray:
    """Open3D voxel downsampling (centroid per occupied voxel); ``voxel`` None or 0: unchanged.

    Args:
        points: ``(N, 3)``.

    Returns:
        ``(K, 3)`` float64, K <= N.
    """
    p = as_numpy(points).reshape(-1, 3)
    if not voxel or len(p) == 0:
        return p
    return np.asarray(_cloud(p).voxel_down_sample(float(voxel)).points)


def nearest_distances(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Unsquared distance from each point of ``src (N, 3)`` to its nearest in ``dst (M, 3)``."""
    return np.asarray(_cloud(src).compute_point_cloud_distance(_cloud(dst)))


def chamfer_points(pred: torch.Tensor | np.ndarray, gt: torch.Tensor | np.ndarray,
                   voxel: float | None = VOXEL) -> dict[str, float]:
    """Chamfer distance between two point clouds, after voxel downsampling.

    Args:
        pred: ``(N, 3)`` predicted surface points.
        gt: ``(M, 3)`` ground-truth surface points (same frame and units).
        voxel: downsampling voxel size (None or 0: no downsampling).

    Returns:
        dict ``cd`` = (acc + comp) / 2, ``acc`` = mean d(pred → gt), ``comp`` = mean d(gt → pred),
        ``n_pred``, ``n_gt`` (point counts after downsampling). An empty ``pred`` gives inf for
        ``cd``, ``acc`` and ``comp``.

    Raises:
        ValueError: ``gt`` is empty (nothing to compare against).
    """
    p = downsample(pred, voxel)
    g = downsample(gt, voxel)
    if len(g) == 0:
        raise ValueError("chamfer_points: the ground-truth point cloud is empty")
    if len(p) == 0:
        inf = float("inf")
        return {"cd": inf, "acc": inf, "comp": inf, "n_pred": 0, "n_gt": len(g)}
    acc = float(nearest_distances(p, g).mean())
    comp = float(nearest_distances(g, p).mean())
    return {"cd": 0.5 * (acc + comp), "acc": acc, "comp": comp, "n_pred": len(p), "n_gt": len(g)}


def depth_to_points(origins: np.ndarray, dirs: np.ndarray, depth: np.ndarray,
                    forward: np.ndarray) -> np.ndarray:
    """Back-project z-depth along rays: ``P = o + d · z / (d · forward)``.

    Args:
        origins: ``(..., 3)`` ray origins (camera centre).
        dirs: ``(..., 3)`` ray directions (any length; the formula is scale-free in ``d``).
        depth: ``(...)`` z-depth: distance along the camera's viewing axis ``forward``.
        forward: ``(3,)`` unit viewing axis (OpenCV camera +z in world).

    Returns:
        ``(..., 3)`` points.
    """
    cos = dirs @ forward
    return origins + dirs * (depth / cos)[..., None]


def mesh_depth_at_views(caster: MeshCaster, cameras: Cameras,
                        rays: RayList | None = None) -> np.ndarray:
    """z-depth of a mesh at the pixel centres of views, 0 where the pixel's ray misses it.

    The depth :func:`view_points` expects, without the pixel averaging of rendered depth (module
    docstring): the true mesh's depth at the pixel centres puts no point in mid-air.

    Args:
        caster: the mesh, ready to cast (in the cameras' frame).
        cameras: ``V`` cameras (OpenCV c2w).
        rays: optional precomputed rays, ``list(iter_view_rays(cameras))``.

    Returns:
        ``(V, H, W)`` float64 z-depth along each camera's viewing axis, in the cameras' units.
    """
    out = []
    for _, o, d, fwd in (rays if rays is not None else iter_view_rays(cameras)):
        t = caster.cast(o, d)["t"]
        out.append(np.where(np.isfinite(t), t * (d @ fwd), 0.0))
    return np.stack(out)


def view_points(caster: MeshCaster, cameras: Cameras, depth: torch.Tensor | np.ndarray,
                masks: torch.Tensor | np.ndarray,
                pred_pixels: Literal["unambiguous", "mask", "all"] = "unambiguous",
                rays: RayList | None = None) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Per-view ground-truth and predicted points (frame of the cameras), before downsampling.

    Args:
        caster: the predicted mesh, ready to cast.
        cameras: ``V`` cameras (OpenCV c2w) in the mesh's frame.
        depth: ``(V, H, W)`` GT z-depth in that frame, 0 on background.
        masks: ``(V, H, W)`` GT coverage (8-bit or [0, 1], see :func:`full_coverage`).
        pred_pixels: which pixels give predicted points (module docstring).
        rays: optional precomputed rays, ``list(iter_view_rays(cameras))``.

    Returns:
        Lists of ``(N_v, 3)`` GT points and ``(K_v, 3)`` predicted points, one entry per view.
    """
    depth = as_numpy(depth)
    full = full_coverage(masks)
    partial = partial_coverage(masks)
    if depth.shape != full.shape or depth.ndim != 3 or depth.shape[0] != len(cameras):
        raise ValueError(f"depth {depth.shape} and masks {full.shape} must be (V, H, W) with "
                         f"V = {len(cameras)} cameras")
    gts, preds = [], []
    for v, o, d, fwd in (rays if rays is not None else iter_view_rays(cameras)):
        if o.shape[:2] != depth.shape[1:]:
            raise ValueError(f"view {v}: rays {o.shape[:2]} but depth {depth.shape[1:]}")
        z = depth[v]
        ok = full[v] & np.isfinite(z) & (z > 0)
        gts.append(depth_to_points(o[ok], d[ok], z[ok], fwd))
        hit = caster.cast(o, d)["t"]
        sel = np.isfinite(hit)
        if pred_pixels == "unambiguous":
            sel &= ~partial[v]
        elif pred_pixels == "mask":
            sel &= full[v]
        elif pred_pixels != "all":
            raise ValueError(f"pred_pixels must be 'unambiguous', 'mask' or 'all', "
                             f"got {pred_pixels!r}")
        preds.append(o[sel] + d[sel] * hit[sel][:, None])
    return gts, preds


def chamfer_at_views(mesh: o3d.geometry.TriangleMesh, cameras: Cameras,
                     depth: torch.Tensor | np.ndarray, masks: torch.Tensor | np.ndarray, *,
                     norm: Normalisation | None = None, voxel: float | None = VOXEL,
                     pred_pixels: Literal["unambiguous", "mask", "all"] = "unambiguous",
                     rays: RayList | None = None) -> dict[str, float]:
    """Chamfer distance of a mesh against test-view depth (the project's protocol).

    ``mesh``, ``cameras`` and ``depth`` must share one frame. Either they are in the scene's
    input frame (``norm=None``), or they are in the unit frame of a :class:`voxnero.data.scene.
    Scene` and ``norm`` maps the points to the input frame before downsampling, so the metric is
    always in input-frame units.

    Args:
        mesh: predicted legacy Open3D triangle mesh.
        cameras: ``V`` test cameras (OpenCV c2w, :class:`voxnero.cameras.cameras.Cameras`).
        depth: ``(V, H, W)`` z-depth along each camera's viewing axis, 0 on background.
        masks: ``(V, H, W)`` coverage masks (8-bit, 255 = full, or fractions in [0, 1]).
        norm: the scene's normalisation when the inputs are in the unit frame.
        voxel: downsampling voxel (input-frame units).
        pred_pixels: which pixels give predicted points (module docstring).
        rays: optional precomputed rays of the views, ``list(iter_view_rays(cameras))``, to
            share them between metrics.

    Returns:
        dict ``cd``, ``acc`` (pred → gt), ``comp`` (gt → pred), ``n_pred``, ``n_gt`` (after
        downsampling), ``n_views``.
    """
    gts, preds = view_points(MeshCaster(mesh), cameras, depth, masks, pred_pixels, rays)
    g = np.concatenate(gts, 0)
    p = np.concatenate(preds, 0)
    if norm is not None:
        g = as_numpy(norm.to_input(g))
        p = as_numpy(norm.to_input(p)) if len(p) else p
    out = chamfer_points(p, g, voxel)
    out["n_views"] = len(cameras)
    return out
