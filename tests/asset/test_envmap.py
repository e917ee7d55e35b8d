"""envmap.exr reloads exactly (float32) and its sidecar states the direction convention."""

from __future__ import annotations

import json

import numpy as np
import torch

from voxnero.asset.envmap import write_envmap
from voxnero.io.exr import read_envmap
from voxnero.render.latlong import envmap_lookup, pixel_dirs


def test_envmap_roundtrip_and_convention(tmp_path):
    g = np.random.default_rng(0)
    img = np.exp(g.normal(0, 2, (16, 32, 3))).astype(np.float32)
    path = write_envmap(tmp_path / "envmap.exr", img, extra={"scene_up": [0, 0, 1]})
    back = read_envmap(path)
    assert back.dtype == np.float32 and np.array_equal(back, img)
    side = json.loads((tmp_path / "envmap.json").read_text())
    assert side["height"] == 16 and side["width"] == 32 and side["scene_up"] == [0, 0, 1]
    assert "atan2(dx, dy)" in side["convention"]["u"]
    # the stated pixel-centre directions look up the stored pixels
    d = pixel_dirs(16, 32)
    got = envmap_lookup(torch.from_numpy(back), d)
    assert torch.allclose(got[1:-1], torch.from_numpy(img)[1:-1], rtol=1e-3, atol=1e-4)
