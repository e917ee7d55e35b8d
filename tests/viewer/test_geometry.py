"""Viewer geometries: frusta and photos where the cameras are, materials per channel."""

from __future__ import annotations

import numpy as np
import pytest

from voxnero.asset.load import load_asset
from voxnero.relight.cameras import orbit_cameras
from voxnero.viewer.geometry import (
    CHANNELS,
    asset_mesh,
    camera_drawables,
    channel_material,
    side_offset,
)


def test_frusta_and_photo_quads_sit_on_the_cameras():
    cams, _ = orbit_cameras(np.zeros(3), 1.0, np.array([0, 0, 1.0]), frames=3, size=16)
    photos = np.random.default_rng(0).random((3, 16, 16, 3)).astype(np.float32)
    ds = camera_drawables(cams, photos, size=0.5)
    assert [d.name for d in ds] == ["frusta", "photo_000", "photo_001", "photo_002"]
    lines = ds[0].geometry
    pts = np.asarray(lines.points)
    centers = cams.centers.double().numpy()
    for c in centers:  # every camera centre is a frustum apex
        assert np.linalg.norm(pts - c, axis=1).min() < 1e-6
    for k in range(3):
        quad = np.asarray(ds[k + 1].geometry.vertices)
        fwd = cams.forward[k].double().numpy()
        # photo corners on the plane at depth `size` in front of camera k
        np.testing.assert_allclose((quad - centers[k]) @ fwd, 0.5, atol=1e-6)
        # and they project to the image corners
        uv, _ = cams.project(quad.astype(np.float32), k)
        np.testing.assert_allclose(np.sort(uv.numpy()[:, 0]), [0, 0, 16, 16], atol=1e-3)


def test_materials_and_mesh(viewer_glb):
    a = load_asset(viewer_glb)
    m = asset_mesh(a)
    assert len(m.triangle_uvs) == 3 * len(m.triangles)
    shaders = {c: channel_material(a, c).shader for c in CHANNELS}
    assert shaders == {"shaded": "defaultLit", "albedo": "defaultUnlit",
                       "metallic": "defaultUnlit", "roughness": "defaultUnlit",
                       "normals": "normals"}
    off = side_offset(a)
    assert abs(off @ a.up) < 1e-9 and np.linalg.norm(off) == pytest.approx(2.2 * a.bounds()[1])
