"""Tests of voxnero/mesh/extract.py against analytic SDFs (sphere, ellipsoid)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.errors import DataError
from voxnero.mesh.extract import extract_mesh


def grid(lo, hi, shape_dhw):
    """Corner-aligned sample positions X, Y, Z of shape (D, H, W), indexed [z, y, x]."""
    d, h, w = shape_dhw
    z = np.linspace(lo[2], hi[2], d)
    y = np.linspace(lo[1], hi[1], h)
    x = np.linspace(lo[0], hi[0], w)
    Z, Y, X = np.meshgrid(z, y, x, indexing="ij")
    return X, Y, Z


def signed_volume(mesh) -> float:
    v = np.asarray(mesh.vertices)
    t = np.asarray(mesh.triangles)
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


LO = np.array([-1.0, -0.9, -0.8])
HI = np.array([1.0, 1.1, 1.2])
C = np.array([0.13, 0.21, 0.34])  # off-centre, off-grid
R = 0.5


def sphere_sdf(shape=(64, 64, 64), c=C, r=R, lo=LO, hi=HI):
    X, Y, Z = grid(lo, hi, shape)
    return np.sqrt((X - c[0]) ** 2 + (Y - c[1]) ** 2 + (Z - c[2]) ** 2) - r


def test_sphere_vertices_on_surface_and_outward():
    mesh = extract_mesh(sphere_sdf(), np.stack([LO, HI]))
    v = np.asarray(mesh.vertices)
    h = 2.0 / 63  # grid step (all axes span 2.0 over 63 intervals)
    # Linear interpolation along a cell edge errs by at most h²·max|f''|/8 in SDF value, and
    # |f''| <= 1/|p| <= 1/(r - h) for the exact sphere SDF near the surface.
    tol = h**2 / (8 * (R - h))
    dev = np.abs(np.linalg.norm(v - C, axis=1) - R)
    assert dev.max() <= tol, (dev.max(), tol)
    # Outward: positive signed volume close to the ball's, and vertex normals point away from c.
    vol = signed_volume(mesh)
    assert vol == pytest.approx(4 / 3 * np.pi * R**3, rel=0.01)
    n = np.asarray(mesh.vertex_normals)
    assert (np.einsum("ij,ij->i", n, v - C) > 0).all()


def test_ellipsoid_axis_order_on_non_cubic_grid():
    a = np.array([0.6, 0.4, 0.25])  # distinct semi-axes along x, y, z
    c = np.array([0.1, -0.05, 0.2])
    shape = (50, 60, 70)  # D, H, W all different
    lo, hi = np.array([-1.0, -0.9, -0.8]), np.array([0.9, 1.3, 1.6])  # spans 1.9, 2.2, 2.4
    X, Y, Z = grid(lo, hi, shape)
    q = np.sqrt(((X - c[0]) / a[0]) ** 2 + ((Y - c[1]) / a[1]) ** 2 + ((Z - c[2]) / a[2]) ** 2)
    sdf = (q - 1.0) * a.min()  # same zero set; values only roughly distances
    mesh = extract_mesh(torch.from_numpy(sdf).float(), torch.from_numpy(np.stack([lo, hi])))
    v = np.asarray(mesh.vertices)
    half = (v.max(0) - v.min(0)) / 2
    step = (hi - lo) / (np.array(shape[::-1]) - 1)  # (dx, dy, dz)
    assert np.all(np.abs(half - a) <= step), (half, a)
    assert np.allclose((v.max(0) + v.min(0)) / 2, c, atol=step.max())
    qv = np.linalg.norm((v - c) / a, axis=1)
    assert np.abs(qv - 1).max() < 0.02
    assert signed_volume(mesh) == pytest.approx(4 / 3 * np.pi * a.prod(), rel=0.02)


def test_torch_and_numpy_inputs_agree_and_level_shifts_radius():
    sdf = sphere_sdf((32, 32, 32))
    b = np.stack([LO, HI])
    m_np = extract_mesh(sdf, b)
    m_t = extract_mesh(torch.from_numpy(sdf), torch.from_numpy(b))
    assert np.allclose(np.asarray(m_np.vertices), np.asarray(m_t.vertices))
    m_lvl = extract_mesh(sdf, b, level=0.1)
    r = np.linalg.norm(np.asarray(m_lvl.vertices) - C, axis=1)
    assert np.abs(r - (R + 0.1)).max() < 2e-3


@settings(max_examples=15, deadline=None)
@given(cx=st.floats(-0.3, 0.3), cy=st.floats(-0.3, 0.3), cz=st.floats(-0.3, 0.3),
       r=st.floats(0.2, 0.6), n=st.integers(20, 36))
def test_random_spheres_within_interpolation_bound(cx, cy, cz, r, n):
    c = np.array([cx, cy, cz])
    lo, hi = np.full(3, -1.0), np.full(3, 1.0)
    mesh = extract_mesh(sphere_sdf((n, n, n), c=c, r=r, lo=lo, hi=hi), np.stack([lo, hi]))
    h = 2.0 / (n - 1)
    dev = np.abs(np.linalg.norm(np.asarray(mesh.vertices) - c, axis=1) - r)
    assert dev.max() <= h**2 / (8 * (r - h)) + 1e-9
    assert signed_volume(mesh) > 0


def test_empty_grid_raises_clear_error():
    with pytest.raises(DataError, match="no crossing of level"):
        extract_mesh(np.ones((8, 8, 8)), [[-1, -1, -1], [1, 1, 1]])
    with pytest.raises(DataError, match="no surface"):
        extract_mesh(-np.ones((8, 8, 8)), [[-1, -1, -1], [1, 1, 1]])


@pytest.mark.parametrize("sdf, bounds, msg", [
    (np.zeros((8, 8)), [[-1, -1, -1], [1, 1, 1]], r"\(D, H, W\)"),
    (np.zeros((8, 8, 8)), [-1, 1], "bounds must be"),
    (np.zeros((8, 8, 8)), [[1, -1, -1], [-1, 1, 1]], "max > min"),
    (np.full((8, 8, 8), np.nan), [[-1, -1, -1], [1, 1, 1]], "non-finite"),
])
def test_bad_inputs(sdf, bounds, msg):
    with pytest.raises(ValueError, match=msg):
        extract_mesh(sdf, bounds)
