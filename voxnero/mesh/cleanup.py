"""Open3D clean-up of an extracted surface: repair, keep the main component(s), smooth.

Two steps use numpy/scipy instead of Open3D for speed (measured on a 524k-triangle
marching-cubes mesh on the shared 2-core machine): connected components with
``scipy.sparse.csgraph`` (0.2 s vs 4.7 s for ``cluster_connected_triangles``), and a numpy count
of triangles per edge so that Open3D's ``remove_non_manifold_edges`` (3.1 s) only runs when a
non-manifold edge exists (marching cubes rarely makes one).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def max_triangles_per_edge(triangles: np.ndarray, n_vertices: int) -> int:
    """Largest number of triangles sharing one undirected edge (> 2: non-manifold).

    Args:
        triangles: ``(F, 3)`` vertex indices.
        n_vertices: number of vertices.
    """
    if len(triangles) == 0:
        return 0
    e = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]],
                                triangles[:, [2, 0]]]), axis=1).astype(np.int64)
    _, counts = np.unique(e[:, 0] * n_vertices + e[:, 1], return_counts=True)
    return int(counts.max())


def triangle_components(vertices: np.ndarray, triangles: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Connected components of a triangle mesh (triangles linked through shared vertices).

    Args:
        vertices: ``(V, 3)``.
        triangles: ``(F, 3)`` vertex indices.

    Returns:
        ``labels (F,)`` component index per triangle and ``areas (K,)`` surface area per
        component.
    """
    n = len(vertices)
    a = np.concatenate([triangles[:, 0], triangles[:, 1]])
    b = np.concatenate([triangles[:, 1], triangles[:, 2]])
    graph = coo_matrix((np.ones(len(a), dtype=np.int8), (a, b)), shape=(n, n))
    _, vlabel = connected_components(graph, directed=False)
    labels = vlabel[triangles[:, 0]]
    p = vertices[triangles]
    tri_area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    _, labels = np.unique(labels, return_inverse=True)  # 0..K-1, components with triangles
    return labels, np.bincount(labels, weights=tri_area)


def _component_mask(mesh: o3d.geometry.TriangleMesh, keep: str | int | float) -> np.ndarray:
    """Boolean ``(F,)`` mask of the triangles to REMOVE for the ``keep`` rule."""
    labels, areas = triangle_components(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    if keep == "all" or len(areas) == 0:
        return np.zeros(len(labels), dtype=bool)
    if keep == "largest":
        kept = np.array([int(np.argmax(areas))])
    elif isinstance(keep, bool):
        raise ValueError(f"keep must be 'largest', 'all', an int or a float, got {keep!r}")
    elif isinstance(keep, int):
        if keep < 1:
            raise ValueError(f"keep={keep}: the number of components to keep must be >= 1")
        kept = np.argsort(-areas, kind="stable")[:keep]
    elif isinstance(keep, float):
        if not 0.0 < keep <= 1.0:
            raise ValueError(f"keep={keep}: a minimum area fraction must lie in (0, 1]")
        kept = np.nonzero(areas >= keep * areas.sum())[0]
        if len(kept) == 0:  # a fraction above every component's share keeps the largest one
            kept = np.array([int(np.argmax(areas))])
    else:
        raise ValueError(f"keep must be 'largest', 'all', an int or a float, got {keep!r}")
    return ~np.isin(labels, kept)


def clean_mesh(mesh: o3d.geometry.TriangleMesh, keep: str | int | float = "largest",
               taubin_iters: int = 0) -> o3d.geometry.TriangleMesh:
    """Repair a marching-cubes mesh and keep its main connected component(s).

    Steps, in order: merge duplicated vertices, remove duplicated and degenerate triangles, remove
    non-manifold edges (dropping the smallest triangles at such an edge, Open3D's rule), select
    connected components (triangles linked through shared vertices) by ``keep``, remove
    unreferenced vertices, optionally apply Taubin smoothing (λ = 0.5, μ = −0.53, which barely
    shrinks the surface), and recompute vertex normals. The input is not modified; the frame is
    unchanged.

    Args:
        mesh: legacy Open3D triangle mesh, any frame.
        keep: ``"largest"`` — the component with the largest surface area; ``"all"``; an ``int``
            n — the n largest components by area; a ``float`` f in (0, 1] — every component with
            at least the fraction f of the total area (the largest one if none has).
        taubin_iters: Taubin smoothing iterations (0 = none).

    Returns:
        A new ``TriangleMesh`` with vertex normals.

    Raises:
        ValueError: an invalid ``keep`` or ``taubin_iters``, or a mesh without triangles.
    """
    if taubin_iters < 0:
        raise ValueError(f"taubin_iters must be >= 0, got {taubin_iters}")
    if len(mesh.triangles) == 0:
        raise ValueError("clean_mesh: the mesh has no triangles")
    m = o3d.geometry.TriangleMesh(mesh)  # deep copy
    m.remove_duplicated_vertices()
    m.remove_duplicated_triangles()
    m.remove_degenerate_triangles()
    if max_triangles_per_edge(np.asarray(m.triangles), len(m.vertices)) > 2:
        m.remove_non_manifold_edges()
    m.remove_unreferenced_vertices()
    drop = _component_mask(m, keep)
    if drop.any():
        m.remove_triangles_by_mask(drop.tolist())
        m.remove_unreferenced_vertices()
    if taubin_iters > 0:
        m = m.filter_smooth_taubin(number_of_iterations=int(taubin_iters))
    m.compute_vertex_normals()
    return m
