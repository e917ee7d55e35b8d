"""Topology of a triangle mesh: genus from the Euler characteristic, per component.

Used where a decision must not change what the surface connects (the opened start of
:func:`voxnero.shape.starts.race`) and by the corpus benchmark (``tools/corpus``) to compare a
reconstruction's genus with the truth's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from voxnero.mesh.cleanup import triangle_components


def genus(triangles: np.ndarray, n_vertices: int | None = None) -> int | None:
    """Total genus of a closed triangle mesh from its Euler characteristic, per component.

    ``g = Σ_c (2 - χ_c) / 2`` with ``χ = V - E + F``.

    Args:
        triangles: ``(F, 3)`` vertex indices.
        n_vertices: number of vertices (default: the largest index + 1); unused ones count not.

    Returns:
        The genus, or None when the mesh is empty or not a closed 2-manifold (an edge not
        shared by exactly two faces), where it is undefined.
    """
    t = np.asarray(triangles, dtype=np.int64)
    if len(t) == 0:
        return None
    n = int(n_vertices if n_vertices is not None else t.max() + 1)
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    edges, counts = np.unique(e, axis=0, return_counts=True)
    if (counts != 2).any():
        return None
    adj = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    ncomp, label = connected_components(adj, directed=False)
    used = np.zeros(n, bool)
    used[t.ravel()] = True
    v = np.bincount(label[used], minlength=ncomp)
    f = np.bincount(label[t[:, 0]], minlength=ncomp)
    ecount = np.bincount(label[edges[:, 0]], minlength=ncomp)
    chi = v - ecount + f
    live = f > 0
    return int(((2 - chi[live]) // 2).sum())


def mesh_topology(mesh: o3d.geometry.TriangleMesh | str | Path) -> tuple[int | None, int]:
    """Genus of the largest connected component (most triangles) of a mesh and the number of
    components.

    Args:
        mesh: an Open3D mesh (not modified) or the path of a mesh file.

    Returns:
        ``(genus, components)``; the genus is None where the largest component is not a closed
        2-manifold, and ``(None, 0)`` for an empty mesh.
    """
    m = o3d.io.read_triangle_mesh(str(mesh)) if isinstance(mesh, (str, Path)) \
        else o3d.geometry.TriangleMesh(mesh)
    m.remove_duplicated_vertices()  # a file may split vertices along seams
    tri = np.asarray(m.triangles)
    if len(tri) == 0:
        return None, 0
    label, _ = triangle_components(np.asarray(m.vertices), tri)
    count = np.bincount(label)
    big = tri[label == int(np.argmax(count))]
    used, inv = np.unique(big, return_inverse=True)
    return genus(inv.reshape(-1, 3), len(used)), len(count)
