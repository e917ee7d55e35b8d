"""Open3D clean-up of an extracted surface: repair, keep the main component(s), smooth."""

from __future__ import annotations

import numpy as np
import open3d as o3d


def _component_mask(mesh: o3d.geometry.TriangleMesh, keep: str | int | float) -> np.ndarray:
    """Boolean ``(F,)`` mask of the triangles to REMOVE for the ``keep`` rule."""
    labels, _, areas = mesh.cluster_connected_triangles()
    labels = np.asarray(labels)
    areas = np.asarray(areas, dtype=np.float64)
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
    connected components (triangles sharing an edge) by ``keep``, remove unreferenced vertices,
    optionally apply Taubin smoothing (λ = 0.5, μ = −0.53, which barely shrinks the surface),
    and recompute vertex normals. The input is not modified; the frame is unchanged.

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
