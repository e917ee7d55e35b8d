"""``voxnero view --screenshot``: headless Open3D pictures of an asset, per channel."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

CHANNELS = ("shaded", "albedo", "roughness", "normals")


@pytest.fixture(scope="module")
def shots(viewer_glb, tmp_path_factory):
    """One `voxnero view` run (one renderer: the first frame compiles Filament's shaders, the
    expensive part) writing a screenshot per channel."""
    out = tmp_path_factory.mktemp("shots") / "shot.png"
    r = subprocess.run([sys.executable, "-m", "voxnero", "view", str(viewer_glb), "--screenshot",
                        str(out), "--channel", ",".join(CHANNELS), "--size", "160x120"],
                       capture_output=True, text=True, timeout=300)
    if r.returncode != 0 and "EGL" in r.stderr + r.stdout and "Vulkan" not in r.stdout:
        pytest.skip(f"no offscreen GL/Vulkan context here: {r.stderr[-300:]}")
    assert r.returncode == 0, r.stderr[-2000:]
    return {c: np.asarray(Image.open(out.with_name(f"shot_{c}.png")).convert("RGB")).astype(int)
            for c in CHANNELS}


def _object(img: np.ndarray) -> np.ndarray:
    """Pixels that differ from the background colour (taken at the corners)."""
    bg = np.median(np.stack([img[0, 0], img[0, -1], img[-1, 0], img[-1, -1]]), 0)
    return np.abs(img - bg).sum(-1) > 12


@pytest.mark.parametrize("channel", CHANNELS)
def test_screenshot_shows_the_object(shots, channel):
    img = shots[channel]
    assert img.shape == (120, 160, 3)
    obj = _object(img)
    # the sphere fills ~80 % of the view height: a disc of ~ pi (0.4 * 120)^2 / (160 * 120)
    assert 0.15 < obj.mean() < 0.6, obj.mean()
    assert obj[60, 80]  # centred
    assert not obj[:, :5].any() and not obj[:, -5:].any()


def test_channel_switch_changes_the_picture(shots):
    obj = _object(shots["albedo"]) & _object(shots["roughness"]) & _object(shots["shaded"])
    diffs = {}
    for a, b in [("shaded", "albedo"), ("albedo", "roughness"), ("roughness", "normals")]:
        diffs[(a, b)] = np.abs(shots[a][obj] - shots[b][obj]).mean()
    assert min(diffs.values()) > 8, diffs
    # roughness is drawn as a grey map varying over the object; albedo is coloured
    r = shots["roughness"][obj]
    assert np.abs(r[:, 0] - r[:, 1]).mean() < 3 and np.abs(r[:, 1] - r[:, 2]).mean() < 3
    assert r[:, 0].std() > 10
    a = shots["albedo"][obj]
    assert np.abs(a[:, 0] - a[:, 2]).mean() > 10


def test_textures_land_where_they_belong(shots):
    """Roughness = 0.5 + z on the sphere (z up, camera without roll): the top of the picture is
    rougher (brighter) than the bottom; albedo red = 0.5 + x grows to the right (camera on the
    -y side looking +y). Scrambled atlas islands (a UV v-flip) break both."""
    img = shots["roughness"][..., 0].astype(float)
    obj = _object(shots["roughness"]) | _object(shots["normals"])
    rows = np.nonzero(obj.any(1))[0]
    top, bot = rows.min() + 5, rows.max() - 5
    assert img[top][obj[top]].mean() > img[bot][obj[bot]].mean() + 60
    red = shots["albedo"][..., 0].astype(float)
    cols = np.nonzero(obj.any(0))[0]
    left, right = cols.min() + 8, cols.max() - 8
    mid = slice(50, 70)
    assert red[mid, right][obj[mid, right]].mean() > red[mid, left][obj[mid, left]].mean() + 40
