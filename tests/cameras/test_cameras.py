"""Cameras: indexing, inverse poses, projection, OpenGL <-> OpenCV converters."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.cameras.cameras import Cameras, opencv_to_opengl, opengl_to_opencv, w2c_to_c2w


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def random_cameras(n: int = 4, seed: int = 0, w: int = 40, h: int = 30) -> Cameras:
    rng = np.random.default_rng(seed)
    c2w = np.tile(np.eye(4), (n, 1, 1))
    K = np.tile(np.eye(3), (n, 1, 1))
    for i in range(n):
        c2w[i, :3, :3] = random_rotation(rng)
        c2w[i, :3, 3] = rng.normal(size=3) * 3
        K[i, 0, 0], K[i, 1, 1] = rng.uniform(30, 60, 2)
        K[i, 0, 2], K[i, 1, 2] = w / 2 + rng.uniform(-3, 3), h / 2 + rng.uniform(-3, 3)
    return Cameras(K, c2w, w, h)


def test_shapes_indexing_and_device():
    cams = random_cameras(5)
    assert len(cams) == 5 and cams.K.dtype == torch.float32 and cams.c2w.shape == (5, 4, 4)
    assert len(cams[2]) == 1 and torch.equal(cams[2].c2w[0], cams.c2w[2])
    assert torch.equal(cams[-1].c2w[0], cams.c2w[4])
    assert len(cams[1:4]) == 3
    sel = cams[torch.tensor([4, 0])]
    assert torch.equal(sel.c2w, cams.c2w[[4, 0]]) and sel.width == 40 and sel.height == 30
    assert len(cams[torch.tensor([True, False, True, False, False])]) == 2
    moved = cams.to("cpu")
    assert moved.device.type == "cpu" and torch.equal(moved.K, cams.K)
    with pytest.raises(IndexError):
        cams[5]


def test_single_K_is_shared_and_3x4_poses_are_padded():
    c2w = torch.eye(4)[:3].expand(3, 3, 4)
    cams = Cameras(torch.eye(3), c2w, 8, 6)
    assert cams.K.shape == (3, 3, 3) and cams.c2w.shape == (3, 4, 4)
    assert torch.equal(cams.c2w[:, 3], torch.tensor([0.0, 0, 0, 1]).expand(3, 4))


def test_w2c_is_inverse_and_centers():
    cams = random_cameras(6, seed=1)
    eye = torch.eye(4).expand(6, 4, 4)
    torch.testing.assert_close(cams.w2c @ cams.c2w, eye, atol=1e-5, rtol=0)
    torch.testing.assert_close(cams.centers, cams.c2w[:, :3, 3])
    # numpy path, 3x4 input
    w2c = cams.w2c.numpy().astype(np.float64)[:, :3]
    np.testing.assert_allclose(w2c_to_c2w(w2c), cams.c2w.numpy(), atol=1e-5)


def test_project_closed_form():
    # camera at the origin looking down +z (OpenCV): u = fx x / z + cx, v = fy y / z + cy
    K = torch.tensor([[50.0, 0, 20], [0, 40, 15], [0, 0, 1]])
    cams = Cameras(K, torch.eye(4), 40, 30)
    pts = torch.tensor([[0.0, 0, 2], [1.0, -0.5, 4], [0.2, 0.3, -1]])
    uv, z = cams.project(pts, 0)
    torch.testing.assert_close(uv, torch.tensor([[20.0, 15], [32.5, 10], [10.0, 3]]))
    torch.testing.assert_close(z, torch.tensor([2.0, 4, -1]))


def test_project_moves_with_camera():
    """Translating the world and the camera together leaves the projection unchanged."""
    cams = random_cameras(3, seed=2)
    rng = np.random.default_rng(0)
    pts = torch.from_numpy(rng.normal(size=(20, 3)).astype(np.float32))
    shift = torch.tensor([1.5, -2.0, 0.7])
    moved = Cameras(cams.K, cams.c2w.clone(), cams.width, cams.height)
    moved.c2w[:, :3, 3] += shift
    for i in range(3):
        a, za = cams.project(pts, i)
        b, zb = moved.project(pts + shift, i)
        torch.testing.assert_close(a, b, atol=2e-3, rtol=1e-4)
        torch.testing.assert_close(za, zb, atol=1e-4, rtol=1e-4)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000))
def test_opengl_opencv_round_trip(seed):
    rng = np.random.default_rng(seed)
    m = np.eye(4)
    m[:3, :3] = random_rotation(rng)
    m[:3, 3] = rng.normal(size=3)
    np.testing.assert_allclose(opencv_to_opengl(opengl_to_opencv(m)), m, atol=0)
    t = torch.from_numpy(m)
    torch.testing.assert_close(opengl_to_opencv(t), torch.from_numpy(opengl_to_opencv(m)))
    # a point straight ahead of an OpenGL camera (camera -z) is at +z for the OpenCV camera,
    # and the OpenGL camera's +y (up) is OpenCV's -y (down)
    cv = opengl_to_opencv(m)
    ahead = m[:3, 3] - 2.0 * m[:3, 2]
    p_cv = np.linalg.inv(cv) @ np.append(ahead, 1)
    np.testing.assert_allclose(p_cv[:3], [0, 0, 2], atol=1e-9)
    np.testing.assert_allclose(cv[:3, 1], -m[:3, 1])
    np.testing.assert_allclose(cv[:3, 3], m[:3, 3])


def test_forward_is_unit_z_axis():
    cams = random_cameras(4, seed=3)
    torch.testing.assert_close(cams.forward, cams.c2w[:, :3, 2], atol=1e-6, rtol=0)
    assert torch.allclose(cams.forward.norm(dim=-1), torch.ones(4))
    assert math.isclose(float(torch.linalg.det(cams.c2w[0, :3, :3])), 1.0, abs_tol=1e-5)


def test_the_tests_look_at_agrees_with_the_package():
    """The tests' own look-at (tests/fixtures/cameras.py, written from the conventions) and the
    package's look_at_opencv / OpenGL converter give the same poses, the pole included."""
    from tests.fixtures.cameras import look_at, world_to_camera
    from voxnero.cameras.cameras import look_at_opencv

    rng = np.random.default_rng(0)
    eyes = np.vstack([rng.normal(size=(16, 3)) * 3, [[0.0, 0.0, 4.0]]])
    target = np.array([0.1, -0.2, 0.3])
    ours = np.stack([look_at(e, target) for e in eyes])
    np.testing.assert_allclose(ours, look_at_opencv(eyes, target), atol=1e-12)
    gl = np.stack([look_at(e, target, convention="opengl") for e in eyes])
    np.testing.assert_allclose(opengl_to_opencv(gl), ours, atol=1e-12)
    np.testing.assert_allclose(w2c_to_c2w(world_to_camera(ours[0]))[:3], ours[0][:3], atol=1e-12)
