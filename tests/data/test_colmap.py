"""COLMAP: quaternions, text/binary round trips, the loader and undistortion."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from tests.fixtures.scenes import SPHERE_C, check_rays_hit_sphere, make_colmap
from voxnero.data.colmap import (
    ColmapCamera,
    ColmapImage,
    ColmapModel,
    load_colmap,
    qvec_to_rotmat,
    read_model,
    rotmat_to_qvec,
    write_model,
)
from voxnero.errors import DataError
from voxnero.io.color import linear_to_srgb
from voxnero.io.images import write_png


def test_quaternion_closed_form():
    th = 0.7  # rotation by th about +z: q = (cos th/2, 0, 0, sin th/2)
    q = np.array([np.cos(th / 2), 0, 0, np.sin(th / 2)])
    R = np.array([[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]])
    np.testing.assert_allclose(qvec_to_rotmat(q), R, atol=1e-12)
    np.testing.assert_allclose(rotmat_to_qvec(R), q, atol=1e-12)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(
    lambda v: np.linalg.norm(v) > 0.1))
def test_quaternion_round_trip(v):
    q = np.asarray(v) / np.linalg.norm(v)
    q = q if q[0] >= 0 else -q
    R = qvec_to_rotmat(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    q2 = rotmat_to_qvec(R)
    if abs(q[0]) < 1e-9:  # q and -q are the same rotation when w = 0
        q2 = q2 * np.sign(q2 @ q)
    np.testing.assert_allclose(q2, q, atol=1e-9)


def _model():
    cams = {3: ColmapCamera(3, "OPENCV", 64, 48, np.array([50.0, 51, 31.5, 23.5, -0.1, 0.02,
                                                             1e-3, -2e-3])),
            7: ColmapCamera(7, "SIMPLE_RADIAL", 32, 24, np.array([30.0, 16, 12, 0.05]))}
    imgs = {2: ColmapImage(2, np.array([0.5, 0.5, -0.5, 0.5]), np.array([0.1, -2.0, 3.5]), 3,
                           "a b.jpg", np.array([[1.25, 2.5], [3.0, 4.75]]),
                           np.array([11, -1], np.int64)),
            5: ColmapImage(5, np.array([1.0, 0, 0, 0]), np.array([0.0, 0, 1]), 7, "c.png",
                           np.zeros((0, 2)), np.zeros(0, np.int64))}
    pts = np.array([[0.1, 0.2, 0.3], [-1e3, 5e-7, 2.0]])
    return ColmapModel(cams, imgs, pts, np.array([[1, 2, 3], [250, 0, 9]], np.uint8),
                       np.array([11, 12], np.int64), np.array([0.5, 1.25]))


@pytest.mark.parametrize("binary", [False, True])
def test_model_write_read_round_trip(tmp_path, binary):
    m = _model()
    write_model(m, tmp_path, binary=binary)
    ext = ".bin" if binary else ".txt"
    assert (tmp_path / f"cameras{ext}").is_file() and (tmp_path / f"points3D{ext}").is_file()
    r = read_model(tmp_path)
    assert set(r.cameras) == {3, 7} and set(r.images) == {2, 5}
    for k, c in m.cameras.items():
        assert (r.cameras[k].model, r.cameras[k].width, r.cameras[k].height) == (
            c.model, c.width, c.height)
        np.testing.assert_array_equal(r.cameras[k].params, c.params)
    for k, im in m.images.items():
        got = r.images[k]
        assert got.name == im.name and got.camera_id == im.camera_id
        np.testing.assert_array_equal(got.qvec, im.qvec)
        np.testing.assert_array_equal(got.tvec, im.tvec)
        np.testing.assert_array_equal(got.xys, im.xys)
        np.testing.assert_array_equal(got.point3d_ids, im.point3d_ids)
    np.testing.assert_array_equal(r.points, m.points)
    np.testing.assert_array_equal(r.colors, m.colors)
    np.testing.assert_array_equal(r.point_ids, m.point_ids)
    np.testing.assert_array_equal(r.errors, m.errors)


@pytest.mark.parametrize("binary", [False, True])
@pytest.mark.parametrize("model", ["PINHOLE", "SIMPLE_PINHOLE"])
def test_loader_rays_reproduce_rendered_sphere(tmp_path, binary, model):
    b = make_colmap(tmp_path, binary=binary, model=model)
    sc = load_colmap(tmp_path)
    assert sc.format == "colmap" and sc.meta["camera_models"] == [model]
    assert not sc.meta["undistorted"]
    sp = sc.split("train")
    assert sp.names == [f"img_{k:02d}" for k in range(5)]
    check_rays_hit_sphere(sp, sc.norm, b.hits["train"], b.margins["train"])
    # normalisation from the sparse points (all on the sphere): robust box of the sphere
    assert sc.meta["normalisation"]["method"].startswith("sparse points")
    np.testing.assert_allclose(sc.norm.center, SPHERE_C, atol=0.06)
    assert 0.9 < sc.norm.scale / (1.1 * np.sqrt(3) * 0.6) < 1.0
    # the cameras have no roll and look slightly down/up at the object: up is near +Z
    assert sc.up @ np.array([0, 0, 1.0]) > 0.9


def test_text_and_binary_give_the_same_scene(tmp_path):
    make_colmap(tmp_path / "t", binary=False)
    make_colmap(tmp_path / "b", binary=True)
    a, b = load_colmap(tmp_path / "t").split("train"), load_colmap(tmp_path / "b").split("train")
    torch.testing.assert_close(a.cameras.c2w, b.cameras.c2w, atol=0, rtol=0)
    torch.testing.assert_close(a.images, b.images, atol=0, rtol=0)


def test_unsupported_model_is_refused_with_the_fix(tmp_path):
    make_colmap(tmp_path)
    p = tmp_path / "sparse" / "0" / "cameras.txt"
    p.write_text(p.read_text().replace("PINHOLE 38 30 41.0 43.0 19.2 14.7",
                                       "OPENCV_FISHEYE 38 30 41.0 43.0 19.2 14.7 0 0 0 0"))
    with pytest.raises(DataError, match="OPENCV_FISHEYE is not supported") as e:
        load_colmap(tmp_path)
    assert "colmap image_undistorter" in str(e.value)


def _distort(x, y, fx, fy, cx, cy, k1, k2, p1, p2):
    """COLMAP's OPENCV model (forward), written from its documentation."""
    u, v = (x - cx) / fx, (y - cy) / fy
    r2 = u * u + v * v
    radial = k1 * r2 + k2 * r2 * r2
    du = u * radial + 2 * p1 * u * v + p2 * (r2 + 2 * u * u)
    dv = v * radial + 2 * p2 * u * v + p1 * (r2 + 2 * v * v)
    return (u + du) * fx + cx, (v + dv) * fy + cy


def test_opencv_model_is_undistorted(tmp_path):
    """Distorted photo = smooth function g of the distorted pixel position; after loading, the
    undistorted pixel q must show g(distort(q))."""
    w, h = 48, 40
    params = (44.0, 45.0, 24.3, 19.6, -0.12, 0.03, 0.004, -0.003)

    def g(x, y):  # smooth linear radiance per channel
        return np.stack([0.5 + 0.3 * np.sin(x / 6.0) * np.cos(y / 5.0),
                         0.4 + 0.004 * x + 0.005 * y, 0.6 + 0.3 * np.cos((x + y) / 9.0)], -1)

    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5, indexing="xy")
    (tmp_path / "images").mkdir()
    write_png(tmp_path / "images" / "a.png", linear_to_srgb(g(xs, ys)), bits=16)
    m = ColmapModel({1: ColmapCamera(1, "OPENCV", w, h, np.array(params))},
                    {1: ColmapImage(1, np.array([1.0, 0, 0, 0]), np.zeros(3), 1, "a.png")},
                    np.zeros((0, 3)))
    write_model(m, tmp_path / "sparse" / "0", binary=True)
    sc = load_colmap(tmp_path, radius=1.0, center=[0, 0, 3])  # one camera: no default
    assert sc.meta["undistorted"]
    sp = sc.split("train")
    np.testing.assert_allclose(sp.cameras.K[0].numpy(),
                               [[44, 0, 24.3], [0, 45, 19.6], [0, 0, 1]], rtol=1e-6)
    xd, yd = _distort(xs, ys, *params)
    inside = (xd > 1) & (xd < w - 1) & (yd > 1) & (yd < h - 1)
    assert inside.mean() > 0.8 and np.abs(xd - xs).max() > 1.0  # real distortion, mostly inside
    expect = g(xd, yd)
    err = np.abs(sp.images[0].numpy() - expect)[inside]
    # bilinear interpolation of g: |g''| / 8 < 0.002 per axis; 16-bit quantisation ~1e-5
    # (measured 0.0022; a half-pixel convention slip would give ~0.025)
    assert err.max() < 0.005, err.max()
    # without undistortion the error would be several times larger
    no_undistort = np.abs(g(xs, ys) - expect)[inside].max()
    assert err.max() < no_undistort / 5, (err.max(), no_undistort)
    # pixels that map outside the photo are black
    outside = (xd < -0.5) | (xd > w + 0.5) | (yd < -0.5) | (yd > h + 0.5)
    if outside.any():
        assert float(sp.images[0].numpy()[outside].max()) == 0.0


def test_images_dir_and_missing_image(tmp_path):
    make_colmap(tmp_path, n=3)
    (tmp_path / "images").rename(tmp_path / "photos")
    with pytest.raises(DataError, match="image file not found") as e:
        load_colmap(tmp_path)
    assert "img_00.png" in str(e.value)
    assert load_colmap(tmp_path, images_dir=tmp_path / "photos").split("train").n == 3


def test_image_size_must_match_camera(tmp_path):
    make_colmap(tmp_path, n=2)
    Image.fromarray(np.zeros((10, 10, 3), np.uint8)).save(tmp_path / "images" / "img_01.png")
    with pytest.raises(DataError, match="COLMAP camera says 38x30") as e:
        load_colmap(tmp_path)
    assert "img_01.png" in str(e.value)


def test_roi_from_points_ignores_far_outliers(tmp_path):
    """A quarter of the sparse points far away (a wall, stray tracks) must not move the region
    of interest off the sphere: it stays within 10 % of the no-outlier one."""
    from tests.fixtures.scenes import SPHERE_C, SPHERE_R
    from voxnero.data.scene import choose_normalisation

    b = make_colmap(tmp_path)
    sc = load_colmap(b.root)
    sp = sc.split("train")
    c2w = sc.norm.c2w_to_unit(sp.cameras.c2w.double().numpy())  # back to the input frame
    c2w[:, :3, 3] = sc.norm.to_input(sp.cameras.c2w[:, :3, 3].double().numpy())
    rng = np.random.default_rng(1)
    v = rng.normal(size=(400, 3))
    pts = SPHERE_C + SPHERE_R * v / np.linalg.norm(v, axis=1, keepdims=True)
    far = SPHERE_C + rng.uniform(-30, 30, size=(130, 3))
    K = sp.cameras.K.double().numpy()
    clean, _ = choose_normalisation(c2w, K, sp.width, sp.height, points=pts)
    dirty, rec = choose_normalisation(c2w, K, sp.width, sp.height,
                                      points=np.concatenate([pts, far]))
    assert rec["points"] == 530 and rec["inliers"] <= 420
    assert np.linalg.norm(dirty.center - clean.center) < 0.1 * SPHERE_R
    assert abs(dirty.scale / clean.scale - 1) < 0.1
    assert clean.scale > SPHERE_R  # the object is inside the region
