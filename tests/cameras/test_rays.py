"""Rays against closed forms: optical axis, projection of points on rays, pixel-centre formula,
downscaling and random pixel sampling."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from voxnero.cameras.cameras import Cameras, opengl_to_opencv
from voxnero.cameras.rays import (
    image_rays,
    pixel_centers,
    pixel_rays,
    pixel_samples,
    random_pixels,
)

DEV = Path(__file__).resolve().parents[2].parent / "shared" / "data"


def _cams(seed=0, n=3, w=40, h=30):
    rng = np.random.default_rng(seed)
    c2w = np.tile(np.eye(4), (n, 1, 1))
    K = np.tile(np.eye(3), (n, 1, 1))
    for i in range(n):
        q, r = np.linalg.qr(rng.normal(size=(3, 3)))
        q *= np.sign(np.diag(r))
        if np.linalg.det(q) < 0:
            q[:, 0] *= -1
        c2w[i, :3, :3] = q
        c2w[i, :3, 3] = rng.normal(size=3) * 2
        K[i, 0, 0], K[i, 1, 1] = rng.uniform(30, 60, 2)
        K[i, 0, 2], K[i, 1, 2] = rng.uniform(10, 30), rng.uniform(8, 22)
    return Cameras(K, c2w, w, h)


def test_principal_point_ray_is_optical_axis():
    cams = _cams()
    idx = torch.arange(3)
    pix = cams.K[:, :2, 2]
    o, d = pixel_rays(cams, idx, pix)
    torch.testing.assert_close(d, cams.c2w[:, :3, 2], atol=1e-6, rtol=0)
    torch.testing.assert_close(o, cams.centers)


def test_camera_dirs_match_kornia_unproject():
    from kornia.geometry.camera import unproject_points

    from voxnero.cameras.rays import camera_dirs

    cams = _cams(seed=5)
    g = torch.Generator().manual_seed(1)
    cam, pix = random_pixels(300, 3, cams.height, cams.width, generator=g, jitter=True)
    K = cams.K[cam]
    ref = unproject_points(pix, torch.ones(300, 1), K)
    torch.testing.assert_close(camera_dirs(K, pix), ref, atol=1e-6, rtol=1e-6)


def test_image_rays_equal_pixel_rays():
    cams = _cams(seed=6)
    o, d = image_rays(cams, 2)
    pix = pixel_centers(cams.height, cams.width).reshape(-1, 2)
    o2, d2 = pixel_rays(cams, torch.full((pix.shape[0],), 2), pix)
    torch.testing.assert_close(d.reshape(-1, 3), d2, atol=1e-6, rtol=0)
    torch.testing.assert_close(o.reshape(-1, 3), o2)


def test_projecting_a_point_on_a_ray_returns_the_pixel():
    cams = _cams(seed=1)
    g = torch.Generator().manual_seed(0)
    cam, pix = random_pixels(500, 3, cams.height, cams.width, generator=g, jitter=True)
    o, d = pixel_rays(cams, cam, pix)
    assert torch.allclose(d.norm(dim=-1), torch.ones(500), atol=1e-6)
    t = torch.rand(500, generator=g) * 5 + 0.5
    p = o + t[:, None] * d
    for c in range(3):
        sel = cam == c
        uv, z = cams.project(p[sel], c)
        torch.testing.assert_close(uv, pix[sel], atol=2e-3, rtol=0)
        # z-depth = t * cos(angle to the axis)
        cos = (d[sel] * cams.forward[c]).sum(-1)
        torch.testing.assert_close(z, t[sel] * cos, atol=1e-4, rtol=1e-4)


def blender_formula_dirs(c2w_gl: np.ndarray, f: float, cx: float, cy: float, w: int, h: int):
    """data/README.md: camera-space ((i+0.5-cx)/f, -(j+0.5-cy)/f, -1), rotated by the
    Blender c2w."""
    i, j = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5, indexing="xy")
    d = np.stack([(i - cx) / f, -(j - cy) / f, -np.ones_like(i)], -1) @ c2w_gl[:3, :3].T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def test_image_rays_match_blender_pixel_formula():
    rng = np.random.default_rng(4)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = q, [1.0, -2.0, 3.0]
    f, cx, cy, w, h = 35.0, 16.0, 12.0, 32, 24
    cams = Cameras(np.array([[f, 0, cx], [0, f, cy], [0, 0, 1]]), opengl_to_opencv(m), w, h)
    o, d = image_rays(cams, 0)
    assert d.shape == (h, w, 3) and o.shape == (h, w, 3)
    np.testing.assert_allclose(d.numpy(), blender_formula_dirs(m, f, cx, cy, w, h), atol=1e-6)
    np.testing.assert_allclose(o.numpy(), np.broadcast_to(m[:3, 3], (h, w, 3)), atol=1e-6)
    # row 0 is the top of the image: its rays point more "up" (camera +y in Blender) than
    # the bottom row's
    up = m[:3, 1]
    assert (d[0] @ torch.from_numpy(up).float()).mean() > (d[-1] @ torch.from_numpy(up).float()
                                                           ).mean()


def test_dev_scene_rays_match_readme_formula():
    path = DEV / "sphere_gold" / "transforms_train.json"
    if not path.is_file():
        pytest.skip(f"dev scenes not found at {DEV}")
    meta = json.loads(path.read_text())
    m = np.asarray(meta["frames"][7]["transform_matrix"])
    w, h = meta["w"], meta["h"]
    f = 0.5 * w / np.tan(0.5 * meta["camera_angle_x"])
    assert f == pytest.approx(351.677, abs=1e-3)
    K = np.array([[f, 0, meta["cx"]], [0, f, meta["cy"]], [0, 0, 1]])
    cams = Cameras(K, opengl_to_opencv(m), w, h)
    _, d = image_rays(cams, 0)
    np.testing.assert_allclose(d.numpy(), blender_formula_dirs(m, f, meta["cx"], meta["cy"], w,
                                                               h), atol=1e-6)


def test_downscaled_image_rays_go_through_block_centres():
    cams = _cams(seed=2, w=40, h=30)
    o, d = image_rays(cams, 1, downscale=4)
    assert d.shape == (7, 10, 3)
    pix = pixel_centers(30, 40, 4)
    assert pix[0, 0].tolist() == [2.0, 2.0] and pix[6, 9].tolist() == [38.0, 26.0]
    o2, d2 = pixel_rays(cams, torch.ones(70, dtype=torch.long), pix.reshape(-1, 2))
    torch.testing.assert_close(d.reshape(-1, 3), d2)
    full = pixel_centers(30, 40)
    assert full[0, 0].tolist() == [0.5, 0.5] and full[29, 39].tolist() == [39.5, 29.5]


def test_random_pixels_centres_jitter_and_reproducibility():
    g = torch.Generator().manual_seed(3)
    cam, pix = random_pixels(20000, 5, 7, 9, generator=g)
    assert cam.dtype == torch.long and cam.min() >= 0 and cam.max() <= 4
    assert torch.all(pix - pix.floor() == 0.5)
    assert pix[:, 0].max() < 9 and pix[:, 1].max() < 7
    # uniform over cameras: each count within 5 binomial standard deviations
    counts = torch.bincount(cam, minlength=5).double()
    sd = (20000 * 0.2 * 0.8) ** 0.5
    assert torch.all((counts - 4000).abs() < 5 * sd)
    # and over the 63 pixels
    flat = (pix[:, 1].floor() * 9 + pix[:, 0].floor()).long()
    pc = torch.bincount(flat, minlength=63).double()
    sdp = (20000 * (1 / 63) * (62 / 63)) ** 0.5
    assert torch.all((pc - 20000 / 63).abs() < 5 * sdp)
    g1, g2 = torch.Generator().manual_seed(9), torch.Generator().manual_seed(9)
    a = random_pixels(100, 3, 5, 5, generator=g1, jitter=True)
    b = random_pixels(100, 3, 5, 5, generator=g2, jitter=True)
    assert torch.equal(a[0], b[0]) and torch.equal(a[1], b[1])
    frac = a[1] - a[1].floor()
    assert frac.min() >= 0 and frac.max() < 1 and frac.std() > 0.2  # ~U[0,1): sd 0.289


DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


@pytest.mark.parametrize("device", DEVICES)
def test_rays_on_device_match_cpu(device):
    cams = _cams(seed=7)
    g = torch.Generator(device=device).manual_seed(0)
    cam, pix = random_pixels(1000, 3, cams.height, cams.width, generator=g, jitter=True)
    assert cam.device.type == device and pix.device.type == device
    on = cams.to(device)
    o, d = pixel_rays(on, cam, pix)
    o_ref, d_ref = pixel_rays(cams, cam.cpu(), pix.cpu())
    torch.testing.assert_close(d.cpu(), d_ref, atol=1e-5, rtol=0)
    torch.testing.assert_close(o.cpu(), o_ref, atol=1e-5, rtol=0)
    oi, di = image_rays(on, 1, downscale=2)
    assert di.device.type == device and di.shape == (15, 20, 3)
    uv, _ = on.project(o + 2.0 * d, 0)
    assert uv.device.type == device


def test_pixel_samples_are_stratified_inside_their_pixel():
    s = pixel_samples(5, 7, 9, torch.Generator().manual_seed(0), window=(1, 2, 3, 4))
    assert s.shape == (3, 4, 9, 2)
    col = torch.arange(2, 6).view(1, 4, 1).float()
    row = torch.arange(1, 4).view(3, 1, 1).float()
    fx, fy = s[..., 0] - col, s[..., 1] - row
    assert bool(((fx >= 0) & (fx < 1) & (fy >= 0) & (fy < 1)).all())
    # one sample in each cell of the 3 x 3 grid of every pixel
    cell = (fy * 3).floor() * 3 + (fx * 3).floor()
    assert bool((cell.sort(-1).values == torch.arange(9).float()).all())
