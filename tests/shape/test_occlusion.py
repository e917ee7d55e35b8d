"""Tests of voxnero/shape/occlusion.py against closed forms.

* A convex sphere never occludes a ray that leaves its surface (d·n > 0): zero hits, for the
  fine icosphere *and* for a coarse marching-cubes extraction of a 48³ SDF grid (the kind of
  mesh the trainer builds), including grazing directions.
* Two spheres: the fraction of hemisphere rays from sphere A that hit sphere B, and the fraction
  of the cameras' reflected rays that hit the object, agree with analytic ray–sphere
  intersection (an independent computation) within the tessellation error.
"""

from __future__ import annotations

import functools

import numpy as np
import open3d as o3d
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.fixtures.cameras import look_at
from voxnero.shape.occlusion import (
    OcclusionTargets,
    mean_edge_length,
    reflected_hit_fraction,
)

CA, RA = np.array([-0.40, -0.10, 0.05]), 0.45
CB, RB = np.array([0.45, 0.15, -0.05]), 0.40
"""The two spheres of ``voxnero synth two_spheres`` (unit frame of the test)."""


def _sphere(center, radius, resolution=60) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=resolution)
    m.translate(np.asarray(center, dtype=np.float64))
    return m


@functools.cache
def _single() -> OcclusionTargets:
    return OcclusionTargets(_sphere([0.0, 0.0, 0.0], 0.6))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _hemisphere(n: np.ndarray, rng: np.random.Generator, min_cos: float = 0.0) -> np.ndarray:
    """Uniform directions on the hemisphere around each unit normal ``n (N, 3)`` with
    ``d·n > min_cos``."""
    d = _unit(rng.normal(size=n.shape))
    d = np.where(((d * n).sum(1) < 0)[:, None], -d, d)
    bad = (d * n).sum(1) <= min_cos
    while bad.any():
        e = _unit(rng.normal(size=(int(bad.sum()), 3)))
        e = np.where(((e * n[bad]).sum(1) < 0)[:, None], -e, e)
        d[bad] = e
        bad = (d * n).sum(1) <= min_cos
    return d


def _t(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a)).float()


def _ray_hits_sphere(o: np.ndarray, d: np.ndarray, c: np.ndarray, r: float) -> np.ndarray:
    """Closed form: does ``o + t d`` (t > 0, unit d) meet the sphere ``|x − c| = r``?"""
    oc = o - c
    b = (oc * d).sum(1)
    disc = b * b - ((oc * oc).sum(1) - r * r)
    sq = np.sqrt(np.maximum(disc, 0.0))
    return (disc > 0) & (-b + sq > 0)


def test_convex_sphere_never_occludes_leaving_rays():
    rng = np.random.default_rng(0)
    n = _unit(rng.normal(size=(20000, 3)))
    x = 0.6 * n
    d = _hemisphere(n, rng)
    occ, valid = _single().test(_t(x), _t(n), _t(d))
    assert bool(valid.all())
    assert float(occ.sum()) == 0.0


@settings(max_examples=60, deadline=None)
@given(theta=st.floats(0.0, np.pi), phi=st.floats(0.0, 2 * np.pi),
       grazing=st.floats(1e-4, 1.0), spin=st.floats(0.0, 2 * np.pi))
def test_convex_sphere_grazing_rays_hypothesis(theta, phi, grazing, spin):
    """Any point, any leaving direction down to grazing (d·n = 1e-4): no hit."""
    n = np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    t1 = _unit(np.cross(n, [0.3, 0.5, 0.8]) + 1e-9)
    t2 = np.cross(n, t1)
    tang = np.cos(spin) * t1 + np.sin(spin) * t2
    d = grazing * n + np.sqrt(1 - grazing ** 2) * tang
    occ, _ = _single().test(_t(0.6 * n[None]), _t(n[None]), _t(d[None]))
    assert float(occ) == 0.0


def test_rays_into_the_surface_are_invalid():
    n = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    d = np.array([[0.0, 0.6, 0.8], [0.0, 0.6, -0.8]])
    occ, valid = _single().test(_t(0.6 * n), _t(n), _t(d))
    assert valid.tolist() == [True, False]
    assert occ[1, 0] == 0.0  # a ray into the sphere would hit it: masked, not a target


def test_marching_cubes_sphere_has_no_self_hits():
    """A 48³ marching-cubes sphere (facets ~4 % of the radius), SDF normals, reflected rays of
    random view directions, including grazing ones: no self-hit with the edge-length offsets;
    a fixed tiny offset without t_near (the old rule) does report self-hits."""
    from voxnero.mesh.extract import extract_mesh

    res, b = 48, 1.05
    ax = np.linspace(-b, b, res)
    z, y, x = np.meshgrid(ax, ax, ax, indexing="ij")
    sdf = np.sqrt(x ** 2 + y ** 2 + z ** 2) - 0.6
    mesh = extract_mesh(sdf.astype(np.float32), np.array([[-b] * 3, [b] * 3]))
    rng = np.random.default_rng(1)
    n = _unit(rng.normal(size=(20000, 3)))  # the SDF gradient at the surface point
    edge = mean_edge_length(mesh)
    v = (0.6 - 0.25 * edge) * n  # a rendered surface point may lie a little inside the facets
    view = _unit(rng.normal(size=n.shape))
    view = np.where(((view * n).sum(1) > 0)[:, None], -view, view)  # seen from outside
    refl = view - 2 * (view * n).sum(1, keepdims=True) * n
    occ, valid = OcclusionTargets(mesh).test(_t(v), _t(n), _t(refl))
    assert bool(valid.all()) and float(occ.sum()) == 0.0
    old = OcclusionTargets(mesh, offset=1e-4 / edge, t_near=0.0)
    assert float(old.test(_t(v), _t(n), _t(refl))[0].mean()) > 0.5


def test_two_spheres_hemisphere_fraction_matches_closed_form():
    mesh = _sphere(CA, RA) + _sphere(CB, RB)
    rng = np.random.default_rng(2)
    n = _unit(rng.normal(size=(40000, 3)))
    x = CA + RA * n
    d = _hemisphere(n, rng)
    occ, valid = OcclusionTargets(mesh).test(_t(x), _t(n), _t(d))
    truth = _ray_hits_sphere(x, d, CB, RB)
    got = occ[:, 0].numpy() > 0.5
    assert bool(valid.all())
    assert truth.mean() > 0.05  # the test has something to find
    assert abs(got.mean() - truth.mean()) < 0.005
    assert (got != truth).mean() < 0.01  # disagreements only at B's silhouette


def _camera_rays(n_cams: int = 24, size: int = 48, dist: float = 3.0, fov_deg: float = 40.0):
    """Pinhole view rays of cameras on a sphere around the origin, looking at it."""
    rng = np.random.default_rng(3)
    eyes = dist * _unit(rng.normal(size=(n_cams, 3)))
    f = 0.5 * size / np.tan(np.radians(fov_deg) / 2)
    u = (np.arange(size) + 0.5 - size / 2) / f
    uu, vv = np.meshgrid(u, u)
    o, d = [], []
    for e in eyes:
        right, down, fwd = look_at(e)[:3, :3].T
        dirs = _unit(fwd + uu.reshape(-1, 1) * right + vv.reshape(-1, 1) * down)
        o.append(np.broadcast_to(e, dirs.shape))
        d.append(dirs)
    return np.concatenate(o), np.concatenate(d)


def _analytic_reflected_fraction(o: np.ndarray, d: np.ndarray) -> float:
    """Independent: nearest analytic sphere hit, exact normal, reflect, closed-form test."""
    ts = []
    for c, r in ((CA, RA), (CB, RB)):
        oc = o - c
        b = (oc * d).sum(1)
        disc = b * b - ((oc * oc).sum(1) - r * r)
        t = -b - np.sqrt(np.maximum(disc, 0.0))
        ts.append(np.where((disc > 0) & (t > 0), t, np.inf))
    ts = np.stack(ts, 1)
    which, t = ts.argmin(1), ts.min(1)
    hit = np.isfinite(t)
    x = o[hit] + t[hit, None] * d[hit]
    c = np.where((which[hit] == 0)[:, None], CA, CB)
    nrm = _unit(x - c)
    refl = d[hit] - 2 * (d[hit] * nrm).sum(1, keepdims=True) * nrm
    other_c = np.where((which[hit] == 0)[:, None], CB, CA)
    other_r = np.where(which[hit] == 0, RB, RA)
    oc = x - other_c
    b = (oc * refl).sum(1)
    disc = b * b - ((oc * oc).sum(1) - other_r ** 2)
    return float(((disc > 0) & (-b + np.sqrt(np.maximum(disc, 0)) > 0)).mean())


def test_reflected_fraction_of_cameras_matches_closed_form():
    o, d = _camera_rays()
    two = _sphere(CA, RA) + _sphere(CB, RB)
    truth = _analytic_reflected_fraction(o, d)
    frac, k = reflected_hit_fraction(two, o, d)
    assert k > 10000 and truth > 0.02
    assert abs(frac - truth) < 0.006
    one, k1 = reflected_hit_fraction(_sphere([0.0, 0.0, 0.0], 0.6), o, d)
    assert k1 > 10000 and one == 0.0
