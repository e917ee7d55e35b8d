"""Tests of voxnero/synth/envmaps.py: procedural, constant and file environment maps."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from voxnero.errors import ConfigError, DataError
from voxnero.io.exr import write_exr
from voxnero.render.latlong import dir_to_uv, pixel_dirs
from voxnero.synth.envmaps import constant_envmap, load_envmap, procedural_envmap


def test_procedural_is_seeded_hdr_and_2_to_1():
    a, la = procedural_envmap(32, seed=3)
    b, _ = procedural_envmap(32, seed=3)
    c, _ = procedural_envmap(32, seed=4)
    assert a.shape == (32, 64, 3) and a.dtype == np.float32
    assert np.isfinite(a).all() and (a > 0).all()
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert a.max() > 20 * np.median(a)  # HDR: a sun far brighter than the sky
    assert {lobe["type"] for lobe in la["lobes"]} == {"sun", "window"}


def test_sky_above_ground_below_and_sun_where_described():
    img, layout = procedural_envmap(64, seed=1)
    d = pixel_dirs(64, 128).numpy()
    lum = img.mean(-1)
    sky = lum[d[..., 2] > 0.5]
    ground = lum[d[..., 2] < -0.3]
    assert np.median(sky) > np.median(ground)
    sun = next(lobe for lobe in layout["lobes"] if lobe["type"] == "sun")
    j, i = np.unravel_index(lum.argmax(), lum.shape)
    ang = math.degrees(math.acos(np.clip(d[j, i] @ np.array(sun["dir"]), -1, 1)))
    assert ang < sun["radius_deg"] + 3.0  # brightest pixel inside the sun disc (+1 px)
    # and the project's mapping puts the sun's direction on that pixel
    uv = dir_to_uv(torch.tensor(sun["dir"], dtype=torch.float32)).numpy()
    assert abs(uv[0] * 128 - 0.5 - i) <= 2.5 or abs(abs(uv[0] * 128 - 0.5 - i) - 128) <= 2.5
    assert abs(uv[1] * 63 - j) <= 2.5


def test_scale_is_linear_and_constant_is_uniform():
    a, _ = procedural_envmap(16, seed=0, scale=1.0)
    b, _ = procedural_envmap(16, seed=0, scale=2.5)
    assert np.allclose(b, 2.5 * a, rtol=1e-6)
    c = constant_envmap(8, 0.7)
    assert c.shape == (8, 16, 3) and np.all(c == np.float32(0.7))


def test_load_envmap_sources(tmp_path):
    img = np.random.default_rng(0).uniform(0.1, 5.0, (16, 32, 3)).astype(np.float32)
    write_exr(tmp_path / "e.exr", img, half=False)
    got, desc = load_envmap(str(tmp_path / "e.exr"), scale=2.0)
    assert np.allclose(got, 2.0 * img) and desc["kind"] == "file"
    got, desc = load_envmap("constant", height=8, constant=3.0)
    assert got.shape == (8, 16, 3) and np.all(got == 3.0) and desc["kind"] == "constant"
    with pytest.raises(ConfigError, match="env.source"):
        load_envmap(str(tmp_path / "e.png"))
    write_exr(tmp_path / "sq.exr", img[:, :16], half=False)
    with pytest.raises(DataError, match="2 x height"):
        load_envmap(str(tmp_path / "sq.exr"))
