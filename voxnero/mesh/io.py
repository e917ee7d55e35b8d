"""Mesh files in the input's own frame.

Inside VoxNeRO meshes live in the unit (working) frame; files on disk are in the frame of the
user's input (the cameras' world). A :class:`voxnero.data.scene.Normalisation` maps between them:
``x_input = x_unit · scale + center``. A uniform scale with ``scale > 0`` and a translation keep
unit normals and the winding unchanged, so only vertex positions are transformed.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import open3d as o3d

from voxnero.errors import DataError

if TYPE_CHECKING:
    from voxnero.data.scene import Normalisation

MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".gltf", ".glb")
"""File types Open3D reads and writes triangle meshes as."""


def _mapped(mesh: o3d.geometry.TriangleMesh, fn) -> o3d.geometry.TriangleMesh:
    out = o3d.geometry.TriangleMesh(mesh)
    v = np.asarray(fn(np.asarray(mesh.vertices, dtype=np.float64)), dtype=np.float64)
    out.vertices = o3d.utility.Vector3dVector(np.ascontiguousarray(v))
    return out


def save_mesh(path: str | Path, mesh: o3d.geometry.TriangleMesh,
              norm: Normalisation | None = None) -> Path:
    """Write ``mesh`` (binary PLY or any type Open3D writes, by suffix) in the input frame.

    Args:
        path: output file; parent folders are created.
        mesh: legacy Open3D mesh in the unit frame (or already in the input frame if ``norm`` is
            None).
        norm: the scene's normalisation; when given, vertices are mapped with
            ``norm.to_input(v) = v · scale + center`` before writing.

    Returns:
        The path written.

    Raises:
        DataError: unsupported suffix or Open3D could not write the file.
    """
    path = Path(path)
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise DataError(f"unsupported mesh file type {path.suffix!r}", path=path,
                        fix=f"use one of {', '.join(MESH_SUFFIXES)}")
    out = _mapped(mesh, norm.to_input) if norm is not None else o3d.geometry.TriangleMesh(mesh)
    if not out.has_vertex_normals():
        out.compute_vertex_normals()
    path.parent.mkdir(parents=True, exist_ok=True)
    if not o3d.io.write_triangle_mesh(str(path), out, write_ascii=False, compressed=False,
                                      write_vertex_normals=True, print_progress=False):
        raise DataError("Open3D could not write the mesh", path=path,
                        fix="check that the folder is writable and the disk not full")
    return path


def load_mesh(path: str | Path, norm: Normalisation | None = None) -> o3d.geometry.TriangleMesh:
    """Read a triangle mesh written in the input frame, optionally mapping it to the unit frame.

    Args:
        path: mesh file (PLY, OBJ, ...).
        norm: when given, vertices are mapped with ``norm.to_unit(v) = (v − center) / scale``.

    Returns:
        A legacy Open3D ``TriangleMesh`` with vertex normals (computed if the file had none).

    Raises:
        DataError: missing, unreadable or empty file.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError("mesh file not found", path=path,
                        fix="give the path of a .ply/.obj mesh or a run folder holding mesh.ply")
    mesh = o3d.io.read_triangle_mesh(str(path), enable_post_processing=False,
                                     print_progress=False)
    if len(mesh.triangles) == 0:
        raise DataError("no triangles could be read from this file (empty, a point cloud or not "
                        "a mesh)", path=path, fix="pass a triangle mesh, e.g. a run's mesh.ply")
    v = np.asarray(mesh.vertices)
    if not np.all(np.isfinite(v)):
        raise DataError("the mesh has non-finite vertex coordinates", path=path,
                        fix="re-export the mesh; NaN vertices usually come from a diverged run")
    if norm is not None:
        mesh = _mapped(mesh, norm.to_unit)
    if not mesh.has_vertex_normals():
        mesh.compute_vertex_normals()
    return mesh


def cut_mesh(mesh: o3d.geometry.TriangleMesh, vid: np.ndarray, triangles: np.ndarray
             ) -> o3d.geometry.TriangleMesh:
    """The mesh re-indexed onto the vertices ``vid`` (a vertex may appear more than once: the
    mesh is cut along the seams that makes; positions and normals are copied, so the surface
    does not move).

    Args:
        mesh: legacy mesh (any frame); vid: (P,) indices into its vertices; triangles: (F, 3)
            indices into ``vid``.

    Returns:
        A new legacy mesh with P vertices (normals of the source's vertices, computed first if
        it had none) and the given triangles; the source itself when ``vid`` is the identity
        and the triangles are its own.
    """
    V = np.asarray(mesh.vertices)
    same = len(vid) == len(V) and np.array_equal(vid, np.arange(len(V))) and \
        np.array_equal(triangles, np.asarray(mesh.triangles))
    if same:
        return mesh
    if not mesh.has_vertex_normals():
        mesh.compute_vertex_normals()
    out = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(V[vid]),
                                    o3d.utility.Vector3iVector(np.asarray(triangles, np.int32)))
    out.vertex_normals = o3d.utility.Vector3dVector(np.asarray(mesh.vertex_normals)[vid])
    return out
