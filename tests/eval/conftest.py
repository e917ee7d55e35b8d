"""Fixtures of the eval tests: analytic sphere views and the dev scenes' test views.

Test modules get the helpers through the session fixture ``geo`` (not ``from conftest import``:
several test folders have a conftest.py, so the module name ``conftest`` is ambiguous).
"""

from __future__ import annotations

import functools
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import open3d as o3d
import pytest

from tests.fixtures.cameras import look_at
from voxnero.cameras.cameras import Cameras
from voxnero.cameras.rays import image_rays

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def ring_cameras(n=6, dist=4.0, size=96, fov_deg=40.0) -> Cameras:
    """``n`` cameras at distance ``dist`` on a tilted ring, looking at the origin."""
    f = 0.5 * size / np.tan(np.radians(fov_deg) / 2)
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]])
    eyes = []
    for i in range(n):
        az, el = 2 * np.pi * i / n, np.radians(-15 + 70 * i / max(n - 1, 1))
        eyes.append(dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]))
    return Cameras(np.stack([K] * n), np.stack([look_at(e) for e in eyes]), size, size)


def sphere_views(cameras: Cameras, center, radius):
    """Exact z-depth, normals and 8-bit masks of an analytic sphere (closed-form intersection).

    Returns:
        depth (V, H, W), normals (V, H, W, 3), masks (V, H, W) uint8 (255 on hit pixel centres).
    """
    c = np.asarray(center, dtype=np.float64)
    depths, normals, masks = [], [], []
    for v in range(len(cameras)):
        o, d = (a.double().numpy() for a in image_rays(cameras, v))
        fwd = cameras.c2w[v, :3, 2].double().numpy()
        oc = o - c
        b = np.einsum("hwi,hwi->hw", oc, d)
        disc = b**2 - (np.einsum("hwi,hwi->hw", oc, oc) - radius**2)
        hit = disc > 0
        t = np.where(hit, -b - np.sqrt(np.maximum(disc, 0)), 0.0)
        p = o + d * t[..., None]
        depths.append(np.where(hit, t * (d @ fwd), 0.0))
        normals.append(np.where(hit[..., None], (p - c) / radius, 0.0))
        masks.append(np.where(hit, 255, 0).astype(np.uint8))
    return np.stack(depths), np.stack(normals), np.stack(masks)


def icosphere(center, radius, subdiv=6) -> o3d.geometry.TriangleMesh:
    """Icosphere with vertices exactly on the sphere and outward winding."""
    m = o3d.geometry.TriangleMesh.create_icosahedron(1.0).subdivide_midpoint(subdiv)
    v = np.asarray(m.vertices)
    v = v / np.linalg.norm(v, axis=1, keepdims=True) * radius + np.asarray(center)
    m.vertices = o3d.utility.Vector3dVector(v)
    m.compute_vertex_normals()
    return m


@functools.lru_cache(maxsize=2)
def _dev_views(name: str):
    """Test views of a dev scene as ``voxnero eval`` sees them, in the scene's UNIT frame.

    Loaded with voxnero.data.detect.load_scene (cameras, z-depth and masks of the test split),
    the GT normals with voxnero.eval.normals.load_gt_normals and the GT mesh mapped into the
    unit frame; ``norm`` maps results back to the input frame, where Chamfer is measured.
    """
    from voxnero.data.detect import load_scene
    from voxnero.eval.normals import load_gt_normals
    from voxnero.mesh.io import load_mesh

    root = DATA / name
    scene = load_scene(root, splits=("test",), eval_extras=True)
    sp = scene.split("test")
    mesh = load_mesh(root / "gt" / "mesh.ply", norm=scene.norm)
    return {"root": root, "cameras": sp.cameras, "depth": sp.depth.numpy(),
            "masks": sp.masks.numpy(), "normals": load_gt_normals(root, "test", sp.names),
            "mesh": mesh, "norm": scene.norm}


@pytest.fixture
def dev_scene():
    """Factory: ``dev_scene("sphere_gold")`` -> dict of test views; skips without the data."""

    def get(name: str):
        if not (DATA / name / "transforms_test.json").is_file():
            pytest.skip(f"dev scene {name} not found under {DATA}")
        return _dev_views(name)

    return get


@pytest.fixture(scope="session")
def geo():
    """Helpers: ``ring_cameras``, ``sphere_views``, ``icosphere``, ``DATA``."""
    return SimpleNamespace(ring_cameras=ring_cameras,
                           sphere_views=sphere_views, icosphere=icosphere, DATA=DATA)

