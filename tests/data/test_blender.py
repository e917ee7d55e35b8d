"""Blender / NeRF-synthetic loader on code-built scenes (analytic sphere, independent render)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.fixtures.scenes import check_rays_hit_sphere, make_blender
from voxnero.data.blender import load_blender
from voxnero.errors import DataError


@pytest.mark.parametrize("ngp_keys", [True, False])
@pytest.mark.parametrize("with_ext", [True, False])
def test_rays_reproduce_rendered_sphere(tmp_path, ngp_keys, with_ext):
    b = make_blender(tmp_path, ngp_keys=ngp_keys, with_ext=with_ext)
    sc = load_blender(tmp_path, splits=("train", "test"))
    assert sc.format == "blender" and sc.up.tolist() == [0, 0, 1]
    assert sc.background == "unknown"
    for s in ("train", "test"):
        sp = sc.split(s)
        assert sp.images.shape == (b.hits[s].shape + (3,)) and sp.alpha is None
        assert sp.names[0] == "r_0"
        check_rays_hit_sphere(sp, sc.norm, b.hits[s], b.margins[s])
    K = sc.split("train").cameras.K[0]
    if ngp_keys:
        assert K.tolist() == [[48.0, 0, 21.0], [0, 46.0, 15.5], [0, 0, 1]]
    else:  # camera_angle_x only: fy = fx, principal point at the image centre
        assert K[0, 0] == pytest.approx(48.0, rel=1e-6) and K[1, 1] == K[0, 0]
        assert K[0, 2] == 20.0 and K[1, 2] == 16.0


def test_images_are_linear(tmp_path):
    b = make_blender(tmp_path, n={"train": 2})
    sp = load_blender(tmp_path).split("train")
    # BG = (20, 40, 230) sRGB -> linear via the exact curve
    srgb = np.array([20, 40, 230]) / 255
    lin = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    bg = sp.images[~b.hits["train"]].numpy()
    np.testing.assert_allclose(bg, np.broadcast_to(lin, bg.shape), atol=1e-6)


def test_per_frame_intrinsics_win(tmp_path):
    make_blender(tmp_path, n={"train": 3})
    p = tmp_path / "transforms_train.json"
    meta = json.loads(p.read_text())
    meta["frames"][1].update(fl_x=60.0, cx=19.0)
    p.write_text(json.dumps(meta))
    K = load_blender(tmp_path).split("train").cameras.K
    assert K[1, 0, 0] == 60.0 and K[1, 0, 2] == 19.0 and K[1, 1, 1] == 46.0
    assert K[0, 0, 0] == 48.0 and K[2, 0, 2] == 21.0


@pytest.mark.parametrize("white", [False, True])
def test_rgba_composited_in_linear_and_alpha_kept(tmp_path, white):
    b = make_blender(tmp_path, n={"train": 2}, rgba=True)
    sc = load_blender(tmp_path, white_bg=white)
    sp = sc.split("train")
    assert sc.background == "alpha" and sp.alpha is not None
    np.testing.assert_array_equal(sp.alpha.numpy() > 0.5, b.hits["train"])
    bg = sp.images[~b.hits["train"]]
    assert bool((bg == (1.0 if white else 0.0)).all())
    fg = sp.images[b.hits["train"]]
    srgb = np.array([200, 120, 40]) / 255
    np.testing.assert_allclose(fg[0].numpy(), ((srgb + 0.055) / 1.055) ** 2.4, atol=1e-6)


def test_normalisation_is_shared_by_splits(tmp_path):
    make_blender(tmp_path)
    a = load_blender(tmp_path, splits=("train",))
    b = load_blender(tmp_path, splits=("test",))
    assert a.norm.to_dict() == b.norm.to_dict()
    assert a.meta["normalisation"]["method"].startswith("cameras")
    c = load_blender(tmp_path, radius=3.0, center=[0, 0, 0])
    assert c.norm.scale == 3.0 and c.meta["normalisation"]["method"] == "user radius/center"


def test_eval_extras_masks(tmp_path):
    from PIL import Image

    b = make_blender(tmp_path, n={"train": 2})
    (tmp_path / "train_mask").mkdir()
    for i in range(2):
        Image.fromarray((b.hits["train"][i] * 255).astype(np.uint8)).save(
            tmp_path / "train_mask" / f"r_{i}.png")
    assert load_blender(tmp_path).split("train").masks is None  # evaluation only
    m = load_blender(tmp_path, eval_extras=True).split("train").masks
    np.testing.assert_array_equal(m.numpy(), b.hits["train"].astype(np.float32))


def test_missing_split_file(tmp_path):
    make_blender(tmp_path, n={"train": 1})
    with pytest.raises(DataError, match=r"split file not found \(have \['transforms_train.json'"):
        load_blender(tmp_path, splits=("val",))


def test_ngp_distortion_is_removed(tmp_path):
    """With k1, k2, p1, p2 the loaded pixel q shows the photo at the distorted position
    distort(q) (COLMAP/OpenCV polynomial, computed here independently)."""
    from voxnero.io.color import srgb_to_linear

    make_blender(tmp_path, n={"train": 2})
    k1, k2, p1, p2 = -0.4, 0.1, 0.003, -0.002
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    meta.update(k1=k1, k2=k2, p1=p1, p2=p2)
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    sc = load_blender(tmp_path)
    assert sc.meta["undistorted"]
    from PIL import Image

    raw = srgb_to_linear(np.asarray(Image.open(tmp_path / "train" / "r_0.png")) / 255.0)
    fx, fy, cx, cy, w, h = 48.0, 46.0, 21.0, 15.5, 40, 32
    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5, indexing="xy")
    u, v = (xs - cx) / fx, (ys - cy) / fy
    r2 = u * u + v * v
    rad = k1 * r2 + k2 * r2 * r2
    xd = (u + u * rad + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)) * fx + cx
    yd = (v + v * rad + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)) * fy + cy
    assert np.abs(xd - xs).max() > 1.0
    # pixels whose 4 bilinear neighbours in the photo share one colour must show that colour
    i0 = np.floor(xd - 0.5).astype(int)
    j0 = np.floor(yd - 0.5).astype(int)
    ok = (i0 >= 0) & (j0 >= 0) & (i0 + 1 < w) & (j0 + 1 < h)
    got = sc.split("train").images[0].numpy()
    checked = 0
    for j, i in zip(*np.nonzero(ok), strict=True):
        a, b = i0[j, i], j0[j, i]
        nb = raw[b:b + 2, a:a + 2].reshape(-1, 3)
        if np.ptp(nb, axis=0).max() == 0:
            np.testing.assert_allclose(got[j, i], nb[0], atol=1e-5)
            checked += 1
    assert checked > 0.7 * w * h
    # the sphere's edge really moved: the loaded image differs from the photo somewhere
    assert np.abs(got - raw).max() > 0.05
