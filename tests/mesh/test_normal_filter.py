"""Edge-preserving filter of vertex normals (voxnero.mesh.normal_filter)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.mesh.normal_filter import bilateral_normals


def _grid(n: int = 24) -> tuple[np.ndarray, np.ndarray]:
    """A regular n × n vertex grid on [0, 1]² (z = 0), two triangles per cell."""
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="xy")
    v = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), \
        idx[1:, 1:].ravel()
    f = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return v, f


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip((a * b).sum(-1), -1, 1)))


def _noisy(n: np.ndarray, deg: float, seed: int = 0) -> np.ndarray:
    g = np.random.default_rng(seed)
    out = n + np.radians(deg) * g.standard_normal(n.shape)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def test_the_speckle_on_a_flat_face_averages_out():
    v, f = _grid()
    true = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    noisy = _noisy(true, 3.0)
    out = bilateral_normals(v, f, noisy)
    before, after = _angle(noisy, true).mean(), _angle(out, true).mean()
    assert after < 0.35 * before, (before, after)


def test_a_sharp_edge_stays_sharp():
    """A roof: the grid folded 90° along x = 0.5. Away from the crease (two rings and more) the
    filter must not pull either face's normals toward the other's (< 0.5°), while the same number
    of rounds of plain averaging would (> 2°)."""
    v, f = _grid()
    left = v[:, 0] <= 0.5
    folded = v.copy()
    folded[~left, 0] = 0.5
    folded[~left, 2] = v[~left, 0] - 0.5
    nl, nr = np.array([0.0, 0.0, 1.0]), np.array([-1.0, 0.0, 0.0])
    true = np.where(left[:, None], nl, nr)
    far = np.abs(v[:, 0] - 0.5) > 2.5 / 23
    out = bilateral_normals(folded, f, true)
    plain = bilateral_normals(folded, f, true, sigma_deg=89.9)
    assert _angle(out[far], true[far]).max() < 0.5
    assert _angle(plain[far], true[far]).max() > 2.0


def test_zero_rounds_is_the_identity_and_a_bad_sigma_is_refused():
    v, f = _grid(6)
    n = _noisy(np.tile([0.0, 0.0, 1.0], (len(v), 1)), 5.0)
    assert np.array_equal(bilateral_normals(v, f, n, rounds=0), n)
    with pytest.raises(ValueError, match="sigma_deg"):
        bilateral_normals(v, f, n, sigma_deg=0.0)


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(1e-4, 1e4), shift=st.floats(-1e3, 1e3))
def test_the_result_is_unit_and_does_not_depend_on_the_frame(scale, shift):
    """Uniform scale and translation (the project's normalisation) change nothing."""
    v, f = _grid(8)
    n = _noisy(np.tile([0.0, 0.0, 1.0], (len(v), 1)), 10.0, seed=3)
    a = bilateral_normals(v, f, n)
    b = bilateral_normals(v * scale + shift, f, n)
    assert np.allclose(np.linalg.norm(a, axis=1), 1.0)
    assert _angle(a, b).max() < 1e-3
