"""Edge-preserving (bilateral) filtering of a mesh's vertex normals, and the mesh's edges.

Stage 1's field normals (:func:`voxnero.shape.run_files.field_normals`) carry a speckle of
voxel-scale bumps (the knot's error image), which a mirror shows and stage 2 then blurs with
roughness. Each round replaces a vertex normal by the normalised weighted sum of itself and its
one-ring neighbours'::

    n_i <- normalize(n_i + sum_j w_ij n_j),
    w_ij = exp(-(|x_i - x_j| / l)^2) * exp(-((1 - n_i . n_j) / (1 - cos sigma))^2)

with ``l`` the mesh's mean edge length: neighbours whose normals differ by much more than
``sigma`` (the two faces of an edge) get no weight, so edges stay sharp while the bumps on a face
average out. Only normals change; positions stay. Any frame (the weights are scale-free).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor


def mesh_edges(triangles: Tensor) -> Tensor:
    """Unique undirected edges of a triangle mesh.

    Args:
        triangles: (F, 3) long vertex indices.

    Returns:
        (E, 2) long vertex pairs, each edge once, smaller index first.
    """
    f = triangles
    e = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    return torch.unique(torch.sort(e, dim=1).values, dim=0)


def bilateral_normals(vertices: np.ndarray, triangles: np.ndarray, normals: np.ndarray,
                      rounds: int = 5, sigma_deg: float = 15.0) -> np.ndarray:
    """Filter vertex normals over the one-ring (see the module docstring).

    Args:
        vertices: (V, 3) positions; triangles: (F, 3) vertex indices; normals: (V, 3) unit.
        rounds: filter rounds (0 returns ``normals`` unchanged).
        sigma_deg: angle scale of the range weight, degrees (0 < sigma < 90).

    Returns:
        (V, 3) float64 unit normals; a vertex whose weighted sum vanishes keeps its normal.
    """
    n = np.asarray(normals, dtype=np.float64).copy()
    if rounds <= 0 or len(triangles) == 0:
        return n
    if not 0.0 < sigma_deg < 90.0:
        raise ValueError(f"sigma_deg must lie in (0, 90), got {sigma_deg}")
    v = np.asarray(vertices, dtype=np.float64)
    e = mesh_edges(torch.as_tensor(np.asarray(triangles, dtype=np.int64))).numpy()
    i, j = np.concatenate([e[:, 0], e[:, 1]]), np.concatenate([e[:, 1], e[:, 0]])
    length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
    ell = max(float(length.mean()), 1e-30)
    ws = np.exp(-(np.linalg.norm(v[i] - v[j], axis=1) / ell) ** 2)
    scale = 1.0 - np.cos(np.radians(sigma_deg))
    for _ in range(rounds):
        w = ws * np.exp(-((1.0 - (n[i] * n[j]).sum(1)) / scale) ** 2)
        acc = n.copy()
        np.add.at(acc, i, w[:, None] * n[j])
        norm = np.linalg.norm(acc, axis=1, keepdims=True)
        n = np.where(norm > 1e-12, acc / np.maximum(norm, 1e-30), n)
    return n
