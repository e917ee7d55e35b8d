"""Relight cameras: scene splits, transforms.json and orbits, all in the input frame."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from voxnero.relight.cameras import orbit_cameras, scaled, scene_cameras, transforms_cameras

DEV = Path("/work/shared/data/sphere_gold")


@pytest.mark.skipif(not DEV.is_dir(), reason="dev scenes not present")
def test_scene_and_transforms_cameras_agree_with_the_readme_projection():
    cams, names, photos = scene_cameras(DEV, "test")
    tcams, tnames = transforms_cameras(DEV / "transforms_test.json")
    assert names == tnames and photos.shape == (16, 256, 256, 3)
    torch.testing.assert_close(cams.c2w, tcams.c2w, atol=1e-5, rtol=0)
    torch.testing.assert_close(cams.K, tcams.K)
    # README: cameras at distance 4 from the origin (input frame), projection formula
    np.testing.assert_allclose(cams.centers.norm(dim=-1).numpy(), 4.0, atol=1e-5)
    fr = json.loads((DEV / "transforms_test.json").read_text())["frames"][3]
    c2w_gl = np.asarray(fr["transform_matrix"])
    P = np.array([0.3, -0.2, 0.5])
    pc = np.linalg.inv(c2w_gl) @ np.append(P, 1)
    f = 0.5 * 256 / math.tan(0.5 * 0.6981317)
    expect = [128 + f * pc[0] / -pc[2], 128 - f * pc[1] / -pc[2]]
    uv, z = cams.project(torch.tensor(P[None], dtype=torch.float32), 3)
    np.testing.assert_allclose(uv[0].numpy(), expect, atol=1e-3)


def test_orbit_geometry():
    center, up = np.array([0.5, -1.0, 2.0]), np.array([0.0, 0.0, 1.0])
    cams, names = orbit_cameras(center, 0.9, up, frames=8, elevation_deg=30.0, distance=5.0,
                                fov_deg=40.0, size=64)
    assert len(names) == 8 and cams.width == 64 and cams.height == 64
    rel = cams.centers.double().numpy() - center
    np.testing.assert_allclose(np.linalg.norm(rel, axis=1), 5.0, atol=1e-5)
    np.testing.assert_allclose(rel[:, 2] / 5.0, math.sin(math.radians(30)), atol=1e-5)
    # consecutive frames 45 degrees apart in azimuth
    az = np.unwrap(np.arctan2(rel[:, 1], rel[:, 0]))
    np.testing.assert_allclose(np.abs(np.diff(az)), math.pi / 4, atol=1e-5)
    for k in range(8):
        uv, z = cams.project(torch.tensor(center[None], dtype=torch.float32), k)
        np.testing.assert_allclose(uv[0].numpy(), [32, 32], atol=1e-3)  # looks at the centre
        c2w = cams.c2w[k].double().numpy()
        assert abs(c2w[:3, 0] @ up) < 1e-6  # no roll: image x is horizontal
        assert c2w[:3, 1] @ up < 0  # image y (down) points down
        # a point above the centre projects above the image centre
        uvu, _ = cams.project(torch.tensor((center + 0.3 * up)[None], dtype=torch.float32), k)
        assert float(uvu[0, 1]) < 32


def test_orbit_auto_distance_fills_80_percent():
    cams, _ = orbit_cameras(np.zeros(3), 1.0, np.array([0, 1.0, 0]), frames=1, fov_deg=40.0)
    d = float(cams.centers.norm())
    # the bounding sphere's angular radius is 0.8 of the half field of view
    assert abs(math.asin(1.0 / d) - 0.8 * math.radians(20)) < 1e-6


def test_scaled_cameras_project_scaled_pixels():
    cams, _ = orbit_cameras(np.zeros(3), 1.0, np.array([0, 0, 1.0]), frames=2, size=64)
    half = scaled(cams, 0.5)
    assert (half.width, half.height) == (32, 32)
    P = torch.tensor([[0.2, 0.1, -0.3]])
    uv, _ = cams.project(P, 1)
    uv2, _ = half.project(P, 1)
    torch.testing.assert_close(uv2, uv * 0.5)
