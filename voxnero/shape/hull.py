"""From the coarse stage's occupancy to the SDF's start: threshold, fill, signed distance.

The coarse density grid (:mod:`voxnero.shape.coarse`) is opaque on the visible surface of the
object and carved in the free space every photo saw through; its inside, hidden from all views,
keeps whatever density it started with. So the start of the SDF is taken topologically:

1. occupied = voxels whose opacity per voxel length exceeds a threshold;
2. everything the outside cannot reach through unoccupied voxels is inside (a flood fill from
   the grid's border, ``scipy.ndimage.binary_fill_holes``), small disconnected specks dropped;
3. the signed distance to that solid by two Euclidean distance transforms, the surface half a
   voxel between an inside and an outside corner.

Grids are ``(D, H, W)`` indexed ``[z, y, x]`` (the convention of :mod:`voxnero.fields.grid`).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def solid(alpha: np.ndarray, threshold: float, keep: float = 0.05, close: int = 0
          ) -> np.ndarray:
    """``(D, H, W)`` bool: the occupied voxels (``alpha > threshold``), closed by ``close``
    iterations of a morphological closing (3×3×3 cube: tunnels up to ``2·close``
    voxels wide are shut, no occupied voxel is removed), with every cavity the border cannot
    reach filled, without the specks: connected parts (26-neighbourhood) smaller than ``keep``
    times the largest are dropped (floaters of the density in space that few views see)."""
    occupied = alpha > threshold
    if close > 0:
        # pad so that the closing's erosion does not eat what touches the border
        pad = np.pad(occupied, close)
        st = ndimage.generate_binary_structure(3, 3)
        occupied = ndimage.binary_closing(pad, st, iterations=close)[
            close:-close, close:-close, close:-close] | occupied
    filled = ndimage.binary_fill_holes(occupied)
    label, n = ndimage.label(filled, structure=np.ones((3, 3, 3), bool))
    if n <= 1:
        return filled
    sizes = np.bincount(label.ravel())[1:]
    big = np.flatnonzero(sizes >= keep * sizes.max()) + 1
    return np.isin(label, big)


def signed_distance(inside: np.ndarray, voxel: float) -> np.ndarray:
    """``(D, H, W)`` signed distance (negative inside, unit-frame length) to the boundary of a
    voxel solid, placed half a voxel outside the last inside corner; +inf/−inf never occur
    (an empty or full grid gives ±(grid size))."""
    if not inside.any():
        return np.full(inside.shape, float(max(inside.shape)) * voxel, np.float32)
    if inside.all():
        return np.full(inside.shape, -float(max(inside.shape)) * voxel, np.float32)
    d_in = ndimage.distance_transform_edt(inside)
    d_out = ndimage.distance_transform_edt(~inside)
    return (np.where(inside, 0.5 - d_in, d_out - 0.5) * voxel).astype(np.float32)


def fitted_box(inside: np.ndarray, bounds: np.ndarray, margin: float, limit: float
               ) -> np.ndarray | None:
    """The cube around a voxel solid, with ``margin`` (unit-frame length) on every side, inside
    ``[-limit, limit]³``: ``(2, 3)`` min and max corners, or None for an empty solid.

    Args:
        inside: ``(D, H, W)`` bool solid on the grid whose corner samples span ``bounds``
            (``(2, 3)``, ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``).
    """
    if not inside.any():
        return None
    idx = np.argwhere(inside)[:, ::-1]  # (z, y, x) -> (x, y, z)
    n = np.array(inside.shape[::-1]) - 1
    step = (bounds[1] - bounds[0]) / n
    lo = bounds[0] + idx.min(0) * step - margin
    hi = bounds[0] + idx.max(0) * step + margin
    centre, half = 0.5 * (lo + hi), 0.5 * float((hi - lo).max())
    half = min(half, limit)
    centre = np.clip(centre, -limit + half, limit - half)
    return np.stack([centre - half, centre + half])
