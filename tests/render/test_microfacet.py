"""Tests of voxnero/render/microfacet.py (GGX D, Smith G, Fresnel, alpha) against closed forms
and quadrature."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from voxnero.render.microfacet import (
    ALPHA_MIN,
    f0_from,
    fresnel_schlick,
    ggx_D,
    roughness_to_alpha,
    schlick_ggx_G,
    smith_G,
    smith_G1,
    smith_G_height_correlated,
)


def _theta_grid(alpha: float, n: int = 20000) -> tuple[np.ndarray, np.ndarray]:
    """Trapezoid nodes/weights on [0, pi/2], geometric near 0 so that the lobe is resolved."""
    t = np.concatenate([[0.0], np.geomspace(alpha * 1e-4, math.pi / 2, n)])
    w = np.zeros_like(t)
    dt = np.diff(t)
    w[:-1] += dt / 2
    w[1:] += dt / 2
    return t, w


@pytest.mark.parametrize("alpha", [ALPHA_MIN, 0.01, 0.1, 0.3, 0.6, 1.0])
def test_ggx_D_projected_area_is_one(alpha):
    # integral over the hemisphere of D(h) cos(theta_h) = 1, by 1-D quadrature in theta (float64)
    t, w = _theta_grid(alpha)
    D = ggx_D(torch.from_numpy(np.cos(t)), torch.tensor(alpha, dtype=torch.float64)).numpy()
    integral = 2 * math.pi * np.sum(w * D * np.cos(t) * np.sin(t))
    assert abs(integral - 1.0) < 1e-4


def test_ggx_D_peak_and_float32_finite():
    a = torch.tensor(ALPHA_MIN)
    d = ggx_D(torch.ones(()), a)
    assert torch.isclose(d, 1 / (math.pi * a**2), rtol=1e-4)
    c = torch.linspace(-1, 1, 10001, requires_grad=True)
    val = ggx_D(c, a)
    val.sum().backward()
    assert torch.isfinite(val).all() and torch.isfinite(c.grad).all()


def test_alpha_clamp():
    r = torch.tensor([-1.0, 0.0, 0.01, 0.5, 1.0, 2.0])
    a = roughness_to_alpha(r)
    ref = torch.tensor([ALPHA_MIN, ALPHA_MIN, ALPHA_MIN, 0.25, 1.0, 1.0])
    assert torch.allclose(a, ref)


@pytest.mark.parametrize("alpha", [0.05, 0.3, 1.0])
def test_smith_G1_matches_lambda_form(alpha):
    # independent form: G1 = 1 / (1 + Lambda), Lambda = (-1 + sqrt(1 + a^2 tan^2)) / 2
    c = torch.linspace(0.01, 1, 200, dtype=torch.float64)
    tan2 = (1 - c**2) / c**2
    lam = (-1 + torch.sqrt(1 + alpha**2 * tan2)) / 2
    assert torch.allclose(smith_G1(c, alpha), 1 / (1 + lam), atol=1e-12)
    g2 = 1 / (1 + lam[:, None] + lam[None, :])
    assert torch.allclose(smith_G_height_correlated(c[:, None], c[None, :], alpha), g2, atol=1e-12)
    assert torch.allclose(smith_G(c[:, None], c[None, :], alpha), (1 / (1 + lam))[:, None]
                          * (1 / (1 + lam))[None, :])


def test_smith_G1_weak_white_furnace():
    # Heitz 2014: integral of G1(v) max(0, v.h) D(h) dh = n.v  (visible projected area)
    alpha = 0.4
    rng = np.random.default_rng(0)
    n = 400
    th, ph = np.meshgrid((np.arange(n) + 0.5) / n * math.pi / 2,
                         (np.arange(2 * n) + 0.5) / n * math.pi, indexing="ij")
    dA = (math.pi / 2 / n) * (math.pi / n) * np.sin(th)
    h = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1)
    for _ in range(3):
        tv = rng.uniform(0.1, 1.4)
        v = np.array([math.sin(tv), 0.0, math.cos(tv)])
        vh = np.clip(h @ v, 0, None)
        D = ggx_D(torch.from_numpy(h[..., 2]), alpha).numpy()
        lhs = smith_G1(torch.tensor(v[2]), alpha).item() * np.sum(vh * D * dA)
        assert abs(lhs - v[2]) < 2e-3


def test_fresnel_and_f0():
    f0 = torch.tensor([0.04, 0.5, 1.0])
    assert torch.allclose(fresnel_schlick(f0, torch.tensor(1.0)), f0)
    assert torch.allclose(fresnel_schlick(f0, torch.tensor(0.0)), torch.ones(3))
    alb = torch.tensor([0.2, 0.4, 0.9])
    assert torch.allclose(f0_from(alb, torch.tensor([0.0])), torch.full((3,), 0.04))
    assert torch.allclose(f0_from(alb, torch.tensor([1.0])), alb)


def test_schlick_ggx_G_in_unit_range():
    c = torch.linspace(0, 1, 50)
    g = schlick_ggx_G(c[:, None], c[None, :], 0.3)
    assert (g >= 0).all() and (g <= 1).all() and g[-1, -1] == 1

