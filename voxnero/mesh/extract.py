"""Marching cubes on a dense SDF grid, in the unit (working) frame.

Grid convention (the one of ``torch.nn.functional.grid_sample`` with ``align_corners=True``):
``sdf[k, j, i]`` is the value at the point ``(x, y, z)`` with
``x = xmin + i·(xmax−xmin)/(W−1)``, ``y = ymin + j·(ymax−ymin)/(H−1)``,
``z = zmin + k·(zmax−zmin)/(D−1)``, i.e. the array is indexed ``[z, y, x]`` and ``bounds`` are
the positions of the first and last samples, not of cell faces.

The SDF is negative inside and positive outside. The returned mesh is wound counter-clockwise seen
from outside, so its face normals point toward positive SDF (outward) and its signed volume is
positive.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
import torch
from skimage import measure

from voxnero.errors import DataError


def _to_numpy(a: torch.Tensor | np.ndarray) -> np.ndarray:
    if isinstance(a, torch.Tensor):
        return a.detach().to("cpu", torch.float64).numpy()
    return np.asarray(a, dtype=np.float64)


def extract_mesh(sdf: torch.Tensor | np.ndarray, bounds: torch.Tensor | np.ndarray,
                 level: float = 0.0) -> o3d.geometry.TriangleMesh:
    """Extract the ``level`` iso-surface of an SDF grid with scikit-image marching cubes.

    Args:
        sdf: ``(D, H, W)`` signed distances (negative inside) indexed ``[z, y, x]``; torch (any
            device) or numpy.
        bounds: ``(2, 3)`` ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``, the positions of the grid's
            corner samples in the unit frame (``align_corners=True``).
        level: iso-value of the surface (0 for the zero level set).

    Returns:
        A legacy Open3D ``TriangleMesh`` in the unit frame, vertices ``(x, y, z)``, faces wound so
        that normals point toward positive SDF, with vertex normals computed. Triangles may still
        be degenerate or come in small floating pieces: see :func:`voxnero.mesh.cleanup.clean_mesh`.

    Raises:
        ValueError: wrong shapes, non-finite values or bounds with max <= min.
        DataError: the grid has no crossing of ``level`` (empty surface).
    """
    vol = _to_numpy(sdf)
    b = _to_numpy(bounds)
    if vol.ndim != 3 or min(vol.shape) < 2:
        raise ValueError(f"sdf must be a (D, H, W) grid with every size >= 2, got {vol.shape}")
    if b.shape != (2, 3):
        raise ValueError("bounds must be (2, 3) [[xmin,ymin,zmin],[xmax,ymax,zmax]], "
                         f"got {b.shape}")
    if not np.all(b[1] > b[0]):
        raise ValueError(f"bounds must have max > min on every axis, got {b.tolist()}")
    if not np.all(np.isfinite(vol)):
        raise ValueError(f"sdf grid has {int((~np.isfinite(vol)).sum())} non-finite values")
    vmin, vmax = float(vol.min()), float(vol.max())
    if not (vmin < level < vmax):
        raise DataError(
            f"the SDF grid {vol.shape} has no crossing of level {level} (values in "
            f"[{vmin:.4g}, {vmax:.4g}]): there is no surface to extract",
            fix="the shape stage produced an empty or all-inside field; check its training log "
                "(diverged or too few steps) or that the grid bounds contain the object")
    d, h, w = vol.shape
    # spacing per array axis (z, y, x)
    spacing = ((b[1, 2] - b[0, 2]) / (d - 1), (b[1, 1] - b[0, 1]) / (h - 1),
               (b[1, 0] - b[0, 0]) / (w - 1))
    # With gradient_direction="descent" (skimage's default) the triangles are counter-clockwise
    # seen from the side of larger values, in skimage's own (z, y, x) frame (checked in
    # tests/mesh/test_extract.py; skimage's docstring is ambiguous about it).
    verts_zyx, faces, _, _ = measure.marching_cubes(
        vol, level=level, spacing=spacing, gradient_direction="descent", allow_degenerate=False)
    verts = verts_zyx[:, ::-1] + b[0]
    # Swapping the x and z axes is a reflection: it reverses the winding, so flip it back.
    faces = faces[:, ::-1]
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.ascontiguousarray(verts, dtype=np.float64)),
        o3d.utility.Vector3iVector(np.ascontiguousarray(faces, dtype=np.int32)))
    mesh.compute_vertex_normals()
    return mesh
