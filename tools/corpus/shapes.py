"""Ground-truth shapes of the corpus: signed distances and package meshes -> watertight meshes.

Every shape ends as one closed triangle mesh in the world frame (+Z up, centred at the origin,
inside the sphere of radius 0.9, like the dev scenes), made by marching cubes on a signed
distance sampled on a regular grid (procedural shapes) or loaded from a registry package
(pybullet's data). Its genus (``voxnero.mesh.topology.genus``, from the Euler characteristic)
lets the benchmark compare the topology of a reconstruction with the truth.

Signed distances are functions ``(N, 3) float32 world points -> (N,) float32`` (negative
inside). Most are exact; unions and cuts (``max``/``min``) are bounds, which is all marching
cubes needs near the zero level.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

SDF = Callable[[np.ndarray], np.ndarray]
BOUND = 0.95
"""Half width of the sampling cube (world units); every shape lies in the sphere of radius 0.9."""


@dataclass
class Mesh:
    """A closed triangle mesh: ``vertices (V, 3)``, ``triangles (F, 3)`` (counter-clockwise
    seen from outside), ``normals (V, 3)`` unit area-weighted vertex normals."""

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray


# ------------------------------------------------------------------------------------------
# signed-distance primitives and operators


def rotation(axis: str, deg: float) -> np.ndarray:
    """(3, 3) rotation by ``deg`` degrees about the world axis ``"x"``, ``"y"`` or ``"z"``."""
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def transformed(sdf: SDF, rot: np.ndarray | None = None,
                offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> SDF:
    """The shape ``sdf`` rotated by ``rot`` (3, 3) then moved by ``offset`` (rigid: exact)."""
    r = np.eye(3) if rot is None else np.asarray(rot, dtype=np.float64)
    o = np.asarray(offset, dtype=np.float32)
    return lambda p: sdf(((p - o) @ r).astype(np.float32))  # inverse of x -> r x + o


def box(half: tuple[float, float, float]) -> SDF:
    """Axis-aligned box of half extents ``half`` centred at the origin (exact)."""
    h = np.asarray(half, dtype=np.float32)

    def f(p: np.ndarray) -> np.ndarray:
        q = np.abs(p) - h
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    return f


def sphere(radius: float) -> SDF:
    """Sphere of ``radius`` at the origin (exact)."""
    return lambda p: np.linalg.norm(p, axis=1) - radius


def torus(major: float, minor: float) -> SDF:
    """Torus around the z axis: ring radius ``major``, tube radius ``minor`` (exact)."""
    return lambda p: np.hypot(np.hypot(p[:, 0], p[:, 1]) - major, p[:, 2]) - minor


def capsule(a: tuple[float, float, float], b: tuple[float, float, float], radius: float) -> SDF:
    """Rod of ``radius`` around the segment ``a``-``b`` with round ends (exact)."""
    a_, b_ = np.asarray(a, dtype=np.float32), np.asarray(b, dtype=np.float32)
    ab = b_ - a_

    def f(p: np.ndarray) -> np.ndarray:
        t = np.clip((p - a_) @ ab / float(ab @ ab), 0.0, 1.0)
        return np.linalg.norm(p - a_ - t[:, None] * ab, axis=1) - radius
    return f


def cylinder_z(radius: float, z0: float, z1: float) -> SDF:
    """Solid cylinder around the z axis between heights ``z0 < z1``, flat ends (exact)."""
    def f(p: np.ndarray) -> np.ndarray:
        d = np.stack([np.hypot(p[:, 0], p[:, 1]) - radius,
                      np.abs(p[:, 2] - 0.5 * (z0 + z1)) - 0.5 * (z1 - z0)], axis=1)
        return np.linalg.norm(np.maximum(d, 0.0), axis=1) + np.minimum(d.max(axis=1), 0.0)
    return f


def union(*parts: SDF) -> SDF:
    """Union (pointwise minimum)."""
    return lambda p: np.min(np.stack([s(p) for s in parts]), axis=0)


def smooth_union(a: SDF, b: SDF, k: float) -> SDF:
    """Union of ``a`` and ``b`` with a fillet of size ``k`` (polynomial smooth minimum)."""
    def f(p: np.ndarray) -> np.ndarray:
        da, db = a(p), b(p)
        h = np.clip(0.5 + 0.5 * (db - da) / k, 0.0, 1.0)
        return db * (1 - h) + da * h - k * h * (1 - h)
    return f


def subtract(a: SDF, *cut: SDF) -> SDF:
    """``a`` minus every shape of ``cut``."""
    return lambda p: np.max(np.stack([a(p)] + [-c(p) for c in cut]), axis=0)


def intersect(*parts: SDF) -> SDF:
    """Intersection (pointwise maximum)."""
    return lambda p: np.max(np.stack([s(p) for s in parts]), axis=0)


def tube_along(curve: np.ndarray, radius: float) -> SDF:
    """Tube of ``radius`` around a closed polyline ``curve (M, 3)`` sampled densely.

    The distance to the curve is the distance to its nearest sample (a k-d tree), exact to
    within half the sample spacing squared over the radius; sample at a spacing below
    ``radius / 10``.
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(curve)

    def f(p: np.ndarray) -> np.ndarray:
        d, _ = tree.query(p, distance_upper_bound=4 * radius, workers=-1)
        return (np.minimum(d, 4 * radius) - radius).astype(np.float32)
    return f


# ------------------------------------------------------------------------------------------
# meshing and topology


def grid_points(res: int, bound: float = BOUND) -> tuple[np.ndarray, float]:
    """Centres of a ``res``³ grid over ``[-bound, bound]³``: ``(res³, 3)`` float32 and spacing."""
    x = np.linspace(-bound, bound, res, dtype=np.float32)
    g = np.stack(np.meshgrid(x, x, x, indexing="ij"), axis=-1).reshape(-1, 3)
    return g, float(x[1] - x[0])


def mesh_sdf(sdf: SDF, res: int = 256, bound: float = BOUND, chunk: int = 1 << 21) -> Mesh:
    """Marching cubes (scikit-image) of the zero level of ``sdf`` on a ``res``³ grid.

    Raises:
        ValueError: the shape touches the sampling cube (it would not be closed).
    """
    from skimage.measure import marching_cubes

    pts, step = grid_points(res, bound)
    vals = np.concatenate([sdf(pts[i:i + chunk]) for i in range(0, len(pts), chunk)])
    vol = vals.reshape(res, res, res)
    border = np.concatenate([vol[[0, -1]].ravel(), vol[:, [0, -1]].ravel(),
                             vol[:, :, [0, -1]].ravel()])
    if (border <= 0).any():
        raise ValueError("the shape reaches the sampling cube's border: it would not be closed")
    verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(step, step, step))
    verts = verts - bound
    # scikit-image's default (gradient_direction="descent") already winds the faces
    # counter-clockwise seen from the positive (outer) side of a signed distance
    return finish(verts, faces)


def finish(vertices: np.ndarray, triangles: np.ndarray) -> Mesh:
    """Merge duplicates, drop degenerate faces, compute area-weighted vertex normals."""
    import open3d as o3d

    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(vertices, np.float64)),
                                  o3d.utility.Vector3iVector(np.asarray(triangles, np.int32)))
    m.remove_duplicated_vertices()
    m.remove_degenerate_triangles()
    m.remove_unreferenced_vertices()
    m.compute_vertex_normals()
    return Mesh(np.asarray(m.vertices), np.asarray(m.triangles), np.asarray(m.vertex_normals))


def normalised(vertices: np.ndarray, radius: float = 0.85) -> np.ndarray:
    """``vertices (V, 3)`` moved so their bounding box centre is the origin, scaled so the
    farthest vertex lies at ``radius``."""
    v = np.asarray(vertices, dtype=np.float64)
    v = v - 0.5 * (v.min(axis=0) + v.max(axis=0))
    return v * (radius / np.linalg.norm(v, axis=1).max())


def package_mesh(relpath: str, up: str = "z", subdivide: int = 0, radius: float = 0.85,
                 remesh_res: int = 0) -> Mesh:
    """A mesh shipped by pybullet's data package, made Z-up, centred and scaled.

    Args:
        relpath: path inside ``pybullet_data`` (e.g. ``"bunny.obj"``).
        up: the mesh's own up axis (``"y"`` meshes are turned so it becomes +Z).
        subdivide: Loop subdivisions (smooths a low-poly mesh).
        radius: farthest vertex from the centre after scaling.
        remesh_res: if > 0, rebuild the surface by marching cubes of the signed distance
            (Open3D ray casting) at this resolution; closes seams of meshes that are not
            watertight.
    """
    import open3d as o3d
    import pybullet_data

    path = f"{pybullet_data.getDataPath()}/{relpath}"
    m = o3d.io.read_triangle_mesh(path)
    m = o3d.geometry.TriangleMesh(m.vertices, m.triangles)  # drop UVs so merging works
    m.remove_duplicated_vertices()
    m.remove_duplicated_triangles()
    m.remove_degenerate_triangles()
    m.remove_unreferenced_vertices()
    if subdivide:
        m = m.subdivide_loop(number_of_iterations=subdivide)
    v = np.asarray(m.vertices)
    if up == "y":
        v = v @ rotation("x", 90.0).T
    v = normalised(v, radius)
    tri = np.asarray(m.triangles)
    if remesh_res:
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(v.astype(np.float32)),
                            o3d.core.Tensor(tri.astype(np.uint32)))

        def sdf(p: np.ndarray) -> np.ndarray:
            return scene.compute_signed_distance(o3d.core.Tensor(p)).numpy()
        return mesh_sdf(sdf, remesh_res)
    return finish(v, tri)


# ------------------------------------------------------------------------------------------
# the corpus's procedural shapes (each inside the sphere of radius 0.9)


def torus_knot(p: int = 2, q: int = 3, scale: float = 0.25, tube: float = 0.085) -> SDF:
    """A (p, q) torus knot tube (genus 1, self-occluding, strands a few tube radii apart)."""
    t = np.linspace(0.0, 2 * math.pi, 20000, endpoint=False)
    r = np.cos(q * t) + 2.0
    curve = scale * np.stack([r * np.cos(p * t), r * np.sin(p * t), -np.sin(q * t)], axis=1)
    return transformed(tube_along(curve, tube), rotation("x", 25.0))


def pretzel() -> SDF:
    """Three flat rings in a row whose tubes merge (genus 3), tilted 20° about x."""
    rings = [transformed(torus(0.28, 0.08), offset=(x, 0.0, 0.0)) for x in (-0.48, 0.0, 0.48)]
    return transformed(union(*rings), rotation("x", 20.0) @ rotation("z", 15.0))


def table() -> SDF:
    """A table: a flat top with sharp edges on four legs 0.05 wide (≈ 4 px at 256², d = 4)."""
    top = transformed(box((0.66, 0.42, 0.04)), offset=(0.0, 0.0, 0.30))
    legs = [capsule((x, y, -0.55), (x, y, 0.30), 0.025) for x in (-0.59, 0.59)
            for y in (-0.35, 0.35)]
    return transformed(union(top, *legs), rotation("z", 20.0))


def frame_cube() -> SDF:
    """A cube with three orthogonal square tunnels (flat faces, sharp edges; genus 5)."""
    cut = [box(h) for h in ((0.6, 0.28, 0.28), (0.28, 0.6, 0.28), (0.28, 0.28, 0.6))]
    return transformed(subtract(box((0.48, 0.48, 0.48)), *cut),
                       rotation("z", 30.0) @ rotation("x", 20.0))


def bowl() -> SDF:
    """A hemispherical bowl 0.06 thick, open upwards, on a ring foot (a deep concavity)."""
    shell = intersect(lambda p: np.abs(np.linalg.norm(p, axis=1) - 0.77) - 0.03,
                      lambda p: p[:, 2] - 0.12)
    foot = subtract(cylinder_z(0.32, -0.86, -0.70), cylinder_z(0.26, -0.9, -0.74))
    return transformed(union(shell, foot), rotation("x", 10.0), offset=(0.0, 0.0, 0.06))


def gear() -> SDF:
    """A gear: 14 teeth with flat faces, a hub hole and four lightening holes (genus 5)."""
    disk = cylinder_z(0.56, -0.08, 0.08)
    teeth = [transformed(box((0.07, 0.05, 0.08)), rotation("z", 360.0 * k / 14),
                         offset=(0.6 * math.cos(2 * math.pi * k / 14),
                                 0.6 * math.sin(2 * math.pi * k / 14), 0.0)) for k in range(14)]
    holes = [cylinder_z(0.14, -0.2, 0.2)] + [
        transformed(cylinder_z(0.08, -0.2, 0.2),
                    offset=(0.34 * math.cos(a), 0.34 * math.sin(a), 0.0))
        for a in (0.4, 0.4 + math.pi / 2, 0.4 + math.pi, 0.4 + 1.5 * math.pi)]
    return transformed(subtract(union(disk, *teeth), *holes), rotation("x", 35.0))


def mug() -> SDF:
    """A mug: a cylindrical cup (open top, concave) with a round handle (genus 1)."""
    cup = subtract(cylinder_z(0.42, -0.5, 0.45), cylinder_z(0.36, -0.44, 0.6))
    ring = transformed(torus(0.2, 0.045), rotation("x", 90.0), offset=(0.42, 0.0, 0.0))
    handle = intersect(ring, lambda p: 0.40 - p[:, 0])  # the half outside the cup wall
    return transformed(union(cup, handle), rotation("z", -30.0), offset=(-0.1, 0.0, 0.0))


def chair() -> SDF:
    """A chair of rods: four legs and two posts 0.06 wide, three back rails (genus 3)."""
    seat = box((0.34, 0.34, 0.035))
    legs = [capsule((x, y, -0.62), (x, y, 0.0), 0.03) for x in (-0.29, 0.29)
            for y in (-0.29, 0.29)]
    posts = [capsule((x, 0.29, 0.0), (x, 0.29, 0.6), 0.03) for x in (-0.29, 0.29)]
    rails = [capsule((-0.29, 0.29, z), (0.29, 0.29, z), 0.022) for z in (0.22, 0.40, 0.58)]
    return transformed(union(seat, *legs, *posts, *rails), rotation("z", 35.0),
                       offset=(0.0, -0.05, 0.02))


def vase() -> SDF:
    """A vase 0.04 thick: a round body, a narrow neck open at the top (a cavity seen only
    through a hole 0.3 wide), genus 0."""
    def solid(r_body: float, r_neck: float, top: float) -> SDF:
        body = transformed(sphere(r_body), offset=(0.0, 0.0, -0.2))
        return smooth_union(body, cylinder_z(r_neck, -0.2, top), 0.15)
    return transformed(subtract(solid(0.5, 0.19, 0.55), solid(0.46, 0.15, 0.8)),
                       rotation("y", 8.0))


def teapot() -> SDF:
    """A teapot: a smooth oval body, a spout 0.1 wide, a round handle (genus 1) and a knob."""
    radii = np.array([0.45, 0.45, 0.32], dtype=np.float32)

    def body(p: np.ndarray) -> np.ndarray:  # ellipsoid (a bound, exact on its surface)
        return (np.linalg.norm(p / radii, axis=1) - 1.0) * float(radii.min())
    spout = capsule((0.3, 0.0, -0.05), (0.66, 0.0, 0.3), 0.05)
    ring = transformed(torus(0.2, 0.035), rotation("x", 90.0), offset=(-0.46, 0.0, 0.0))
    handle = intersect(ring, lambda p: p[:, 0] + 0.3)  # its ends inside the body
    knob = transformed(sphere(0.07), offset=(0.0, 0.0, 0.34))
    return transformed(union(smooth_union(body, spout, 0.04), handle, knob),
                       rotation("z", -20.0), offset=(-0.05, 0.0, 0.0))


def cow() -> SDF:
    """A stylised cow (the held-out scene): a body and a head joined by a neck, four legs 0.07
    wide, two horns and a tail 0.036 wide (about 3 px at 63 % fill), genus 0."""
    body = smooth_union(capsule((-0.32, 0.0, 0.12), (0.26, 0.0, 0.14), 0.2),
                        capsule((0.3, 0.0, 0.22), (0.5, 0.0, 0.3), 0.1), 0.08)
    head = smooth_union(body, capsule((0.52, 0.0, 0.32), (0.66, 0.0, 0.2), 0.085), 0.05)
    legs = [capsule((x, y, 0.0), (x, y, -0.62), 0.035) for x in (-0.3, 0.22)
            for y in (-0.11, 0.11)]
    horns = [capsule((0.52, 0.06 * s, 0.38), (0.48, 0.2 * s, 0.52), 0.018) for s in (-1, 1)]
    tail = capsule((-0.5, 0.0, 0.2), (-0.6, 0.0, -0.2), 0.018)
    return transformed(union(head, *legs, *horns, tail), rotation("z", 25.0),
                       offset=(0.0, 0.0, 0.1))


def ladle() -> SDF:
    """A ladle (held out, session 51): a shallow spherical dish 0.05 thick, 0.25 deep, open
    upwards, and a handle 0.07 wide rising from its rim (a shallow concavity, genus 0)."""
    dish = intersect(lambda p: np.abs(np.linalg.norm(p - np.array([0.0, 0.0, 0.45]), axis=1)
                                      - 0.7) - 0.025,
                     lambda p: p[:, 2])
    handle = capsule((0.52, 0.0, -0.02), (0.95, 0.0, 0.5), 0.035)
    return transformed(union(dish, handle), rotation("z", 30.0), offset=(-0.15, 0.0, -0.13))


def hammer() -> SDF:
    """A hammer standing on its handle's end (held out, session 51): a handle 0.1 wide and a
    head with flat faces and a claw split by a notch (two materials split at z = 0.4)."""
    handle = capsule((0.0, 0.0, -0.75), (0.0, 0.0, 0.5), 0.05)
    head = box((0.4, 0.08, 0.1))
    face = transformed(cylinder_z(0.09, -0.12, 0.12), rotation("y", 90.0), offset=(0.4, 0.0, 0.0))
    notch = transformed(box((0.2, 0.02, 0.2)), offset=(-0.42, 0.0, 0.0))
    top = transformed(subtract(union(head, face), notch), offset=(0.0, 0.0, 0.55))
    return transformed(union(handle, top), rotation("z", -35.0))

