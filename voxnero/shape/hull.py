"""From the coarse stage's occupancy to the SDF's start: threshold, fill, signed distance.

The coarse density grid (:mod:`voxnero.shape.coarse`) is opaque on the visible surface of the
object and carved in the free space every photo saw through; its inside, hidden from all views,
keeps whatever density it started with. So the start of the SDF is taken topologically:

1. occupied = voxels whose opacity per voxel length exceeds a threshold;
2. everything the outside cannot reach through unoccupied voxels is inside (a flood fill from
   the grid's border, ``scipy.ndimage.binary_fill_holes``), small disconnected specks dropped;
3. the signed distance to that solid by two Euclidean distance transforms, the surface half a
   voxel between an inside and an outside corner.

With ``coarse.bg_grow`` the filled solid first grows, by a few voxels at most, into the corners
the photos show as object rather than background (:func:`grow_seen_as_object`), where a
mirror's density sat below its face.

Grids are ``(D, H, W)`` indexed ``[z, y, x]`` (the convention of :mod:`voxnero.fields.grid`).
"""

from __future__ import annotations

from collections.abc import Callable

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


def grow_seen_as_object(inside: np.ndarray, ratio_of: Callable[[np.ndarray], np.ndarray],
                        grow: int, quantile: float = 0.95, core_erode: int = 2,
                        core_samples: int = 20000, seed: int = 0
                        ) -> tuple[np.ndarray, dict]:
    """Grow a voxel solid into the corners next to it that the photos show as object.

    A mirror's density can sit below its shiny face (the reflections drawn as a virtual image
    under it), so the density's solid misses a face that every photo shows as object against
    the background (the gear's tooth tops, docs/STAGE1.md finding 38). ``ratio_of`` gives, for
    grid corners, the fraction of the views seeing them whose pixel the background explains:
    near 0 for a corner inside the object's outline in every view, large for free space. The
    classification of pixels errs on the object (a reflection can match the background), so
    the threshold is the ``quantile`` of the ratio over the solid's core (eroded by
    ``core_erode``; at most ``core_samples`` corners), and the corners within ``grow``
    6-neighbour steps outside the solid whose ratio is at most that are added; the result is
    re-filled by :func:`solid`'s rules. The solid only grows, by ``grow`` voxels at most.

    Args:
        inside: ``(D, H, W)`` bool solid.
        ratio_of: maps a ``(D, H, W)`` bool selection to the ratios of its corners, ``(K,)``
            in the order of ``np.argwhere`` (C order).
        grow: most voxels the solid grows; 0 returns it unchanged.

    Returns:
        The grown solid and its evidence: the threshold, the corners tried and added.
    """
    if grow <= 0 or not inside.any():
        return inside, {"added": 0}
    core = ndimage.binary_erosion(inside, iterations=core_erode)
    if not core.any():
        core = inside
    idx = np.flatnonzero(core)
    if idx.size > core_samples:
        idx = np.random.default_rng(seed).choice(idx, core_samples, replace=False)
    pick = np.zeros(inside.size, bool)
    pick[idx] = True
    thr = float(np.quantile(ratio_of(pick.reshape(inside.shape)), quantile))
    st = ndimage.generate_binary_structure(3, 1)
    shell = ndimage.binary_dilation(inside, st, iterations=grow) & ~inside
    add = np.zeros_like(inside)
    add[shell] = ratio_of(shell) <= thr
    grown = solid((inside | add).astype(np.float32), 0.5)
    return grown, {"threshold": round(thr, 4), "shell": int(shell.sum()),
                   "added": int(add.sum()), "grown": int(grown.sum() - inside.sum())}
