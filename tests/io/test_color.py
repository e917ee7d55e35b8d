"""sRGB curve: closed-form values, exact inverse, continuity at the knee, numpy == torch."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.io.color import LINEAR_KNEE, SRGB_KNEE, linear_to_srgb, srgb_to_linear, tonemap

unit = st.floats(0.0, 1.0, allow_nan=False)


def test_closed_form_values():
    # 0.5 linear -> 1.055 * 0.5^(1/2.4) - 0.055; 0.5 encoded -> ((0.5 + 0.055) / 1.055)^2.4
    assert float(linear_to_srgb(np.float64(0.5))) == pytest.approx(0.7353569830524495, abs=1e-12)
    assert float(srgb_to_linear(np.float64(0.5))) == pytest.approx(0.21404114048223255, abs=1e-12)
    assert float(linear_to_srgb(np.float64(0.001))) == pytest.approx(0.01292, abs=1e-12)
    for v in (0.0, 1.0):
        assert float(linear_to_srgb(np.float64(v))) == pytest.approx(v, abs=1e-12)
        assert float(srgb_to_linear(np.float64(v))) == pytest.approx(v, abs=1e-12)


def test_encode_clips_to_unit_interval():
    x = np.array([-1.0, -1e-6, 1.0 + 1e-6, 7.0])
    np.testing.assert_allclose(linear_to_srgb(x), [0.0, 0.0, 1.0, 1.0], atol=1e-12)


@settings(max_examples=300, deadline=None)
@given(unit)
def test_decode_inverts_encode(x):
    assert float(srgb_to_linear(linear_to_srgb(np.float64(x)))) == pytest.approx(x, abs=1e-12)


@settings(max_examples=300, deadline=None)
@given(unit)
def test_encode_inverts_decode(v):
    # the standard's two knees (0.04045 / 12.92 = 0.00313080 vs 0.0031308) disagree by 5e-9,
    # which leaves a 3e-8 round-trip error just below 0.04045; everywhere else it is exact
    tol = 1e-7 if abs(v - SRGB_KNEE) < 1e-6 else 1e-12
    assert float(linear_to_srgb(srgb_to_linear(np.float64(v)))) == pytest.approx(v, abs=tol)


@settings(max_examples=200, deadline=None)
@given(st.floats(1e-9, 1e-4))
def test_continuous_at_knee(eps):
    # both pieces meet at the knee to ~1e-8 (the standard's constants), so a jump across it is
    # bounded by (largest slope near the knee, +5 %) * 2 eps + 1e-7
    lo, hi = np.float64(LINEAR_KNEE - eps), np.float64(LINEAR_KNEE + eps)
    assert abs(float(linear_to_srgb(hi) - linear_to_srgb(lo))) <= 1.05 * 12.92 * 2 * eps + 1e-7
    lo, hi = np.float64(SRGB_KNEE - eps), np.float64(SRGB_KNEE + eps)
    assert abs(float(srgb_to_linear(hi) - srgb_to_linear(lo))) <= 1.05 * 2 * eps / 12.92 + 1e-7


def test_pieces_agree_at_knee():
    power = 1.055 * LINEAR_KNEE ** (1 / 2.4) - 0.055
    assert 12.92 * LINEAR_KNEE == pytest.approx(power, abs=1e-7)
    assert SRGB_KNEE / 12.92 == pytest.approx(((SRGB_KNEE + 0.055) / 1.055) ** 2.4, abs=1e-7)


@settings(max_examples=50, deadline=None)
@given(st.lists(unit, min_size=2, max_size=50))
def test_monotonic(xs):
    xs = np.sort(np.asarray(xs))
    assert np.all(np.diff(linear_to_srgb(xs)) >= 0)
    assert np.all(np.diff(srgb_to_linear(xs)) >= 0)


def test_numpy_and_torch_agree_and_keep_type():
    x = np.linspace(-0.1, 1.2, 1001).astype(np.float32)
    t = torch.from_numpy(x)
    for f in (linear_to_srgb, srgb_to_linear, tonemap):
        a, b = f(x), f(t)
        assert isinstance(a, np.ndarray) and a.dtype == np.float32
        assert isinstance(b, torch.Tensor) and b.dtype == torch.float32
        np.testing.assert_allclose(a, b.numpy(), atol=1e-6)


def test_torch_gradient_finite_at_zero():
    x = torch.tensor([0.0, 0.5, 1.0], requires_grad=True)
    linear_to_srgb(x).sum().backward()
    assert torch.isfinite(x.grad).all()
    assert x.grad[0] == pytest.approx(12.92)


def test_tonemap_closed_form():
    # Reinhard x/(1+x) then sRGB: 1 -> srgb(0.5); exposure multiplies the input
    assert float(tonemap(np.float64(1.0))) == pytest.approx(float(linear_to_srgb(0.5)))
    x = np.array([0.0, 0.3, 2.0, 50.0, 1e6])
    np.testing.assert_allclose(tonemap(x, exposure=2.0), tonemap(2.0 * x), atol=1e-12)
    y = tonemap(x)
    assert y[0] == 0 and np.all(np.diff(y) > 0) and np.all(y < 1)


@given(st.floats(0.0, 1.0))
def test_srgb_slope_is_the_derivative_of_the_encoding(x):
    """srgb_slope equals a central finite difference of linear_to_srgb (float64, step 1e-7,
    away from the knee where the curve has a kink) and agrees between numpy and torch; at or
    above 1 it is the slope at 1 (the encoding clips there)."""
    from voxnero.io.color import LINEAR_KNEE, srgb_slope

    h = 1e-7
    if abs(x - LINEAR_KNEE) > 2 * h and h < x < 1 - h:
        fd = (linear_to_srgb(np.float64(x + h)) - linear_to_srgb(np.float64(x - h))) / (2 * h)
        assert abs(float(srgb_slope(np.float64(x))) - fd) < 1e-5 * max(1.0, fd)
    t = float(srgb_slope(torch.tensor(x, dtype=torch.float64)))
    assert abs(t - float(srgb_slope(np.float64(x)))) < 1e-12
    assert float(srgb_slope(np.float64(3.0))) == float(srgb_slope(np.float64(1.0)))
