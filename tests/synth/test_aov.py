"""Tests of voxnero/synth/aov.py (through render_views): coverage and per-pixel GT maps."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from voxnero.render.envmap import EnvMap
from voxnero.synth.camera_rig import make_cameras
from voxnero.synth.envmaps import constant_envmap
from voxnero.synth.materials import Material, MaterialTable
from voxnero.synth.shapes import Sphere, Union
from voxnero.synth.views import render_views


@pytest.mark.parametrize("res, r", [(64, 0.5), (48, 0.8)])
def test_coverage_sums_to_the_projected_disc_area(res, r):
    """A sphere on the optical axis projects to a disc of radius f·tan(asin(r/D)) pixels."""
    cams = make_cameras(np.array([[0.0, -1.0, 0.0]]), res, fov_deg=40.0, distance=4.0)
    geo = Union([Sphere((0.0, 0.0, 0.0), r)])
    mats = MaterialTable.from_materials([Material((0.2, 0.4, 0.6), 0.3, 0.7)])
    env = EnvMap(torch.as_tensor(constant_envmap(8, 1.0)))
    _, maps = render_views(geo, mats, env, cams, [0], spp=16, max_depth=1,
                           generator=torch.Generator().manual_seed(0))
    cov = maps["coverage"][0]
    f = cams.K[0, 0, 0].item()
    area = math.pi * (f * math.tan(math.asin(r / 4.0))) ** 2
    assert cov.sum().item() == pytest.approx(area, abs=0.01 * area)
    assert cov.min() >= 0 and cov.max() <= 1
    partial = (cov > 0) & (cov < 1)
    assert partial.sum() > 0  # anti-aliased silhouette
    full = cov == 1
    # material maps are exact on covered pixels, zero on background
    assert torch.allclose(maps["albedo"][0][full], torch.tensor([0.2, 0.4, 0.6]))
    assert torch.allclose(maps["metallic"][0][full], torch.tensor(0.3))
    assert torch.allclose(maps["roughness"][0][full], torch.tensor(0.7))
    bg = cov == 0
    assert (maps["depth"][0][bg] == 0).all() and (maps["normal"][0][bg] == 0).all()
    # the centre pixel looks straight at the sphere: depth D − r, normal toward the camera
    c = res // 2
    assert maps["depth"][0][c, c].item() == pytest.approx(4.0 - r, abs=2e-3)
    assert torch.allclose(maps["normal"][0][c, c], torch.tensor([0.0, -1.0, 0.0]), atol=0.05)
