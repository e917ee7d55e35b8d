"""Tests of voxnero/render/encoding.py: IDE shape, limits and finiteness."""

from __future__ import annotations

import math

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.render.encoding import ide
from voxnero.render.sh import sh_basis

SPECIAL = [(0.0, 0.0, 1.0), (0.0, 0.0, -1.0), (0.0, 0.0, 0.0), (1e-30, 0.0, 1.0), (1.0, 0.0, 0.0),
           (0.0, -1.0, 0.0), (3.0, 4.0, 0.0), (1e-7, -1e-7, -1.0)]


@settings(max_examples=25, deadline=None)
@given(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)))
def test_sh_and_ide_finite_everywhere(v):
    d = torch.tensor([v] + SPECIAL, requires_grad=True)
    r = torch.tensor([[0.0]] * len(d), requires_grad=True)
    out = sh_basis(d, 16).sum() + ide(d, r).sum()
    out.backward()
    assert torch.isfinite(out) and torch.isfinite(d.grad).all() and torch.isfinite(r.grad).all()


def test_ide_shape_and_sh_limit():
    g = torch.Generator().manual_seed(1)
    d = torch.nn.functional.normalize(torch.randn(64, 3, generator=g, dtype=torch.float64), dim=-1)
    e0 = ide(d, torch.zeros(64, 1, dtype=torch.float64))
    assert e0.shape == (64, 72)
    Y = sh_basis(d, 16)
    levels = (1, 2, 4, 8, 16)
    # IDE(r = 0): Re part of complex Y_l^m = real SH / sqrt(2) (m > 0), Y_l0 (m = 0)
    k = 0
    for l in levels:
        for m in range(l + 1):
            ref_re = Y[:, l * l + l] if m == 0 else Y[:, l * l + l + m] / math.sqrt(2)
            ref_im = torch.zeros_like(ref_re) if m == 0 else Y[:, l * l + l - m] / math.sqrt(2)
            assert torch.allclose(e0[:, k], ref_re, atol=1e-12)
            assert torch.allclose(e0[:, 36 + k], ref_im, atol=1e-12)
            k += 1
    # roughness -> 0 converges continuously to the SH values
    e_small = ide(d, torch.full((64, 1), 1e-3, dtype=torch.float64))
    assert (e_small - e0).abs().max() < 136 * 1e-6 * e0.abs().max() + 1e-12
    # attenuation exp(-l(l+1) alpha / 2) with alpha = r^2
    r = 0.3
    e = ide(d, torch.full((64, 1), r, dtype=torch.float64))
    assert torch.allclose(e[:, 2:5], e0[:, 2:5] * math.exp(-3 * r * r))  # l = 2: columns 2-4


def test_ide_matches_vmf_expectation_for_large_kappa():
    # E_{w ~ vMF(mu, kappa)}[Y_lm(w)] = A_l(kappa) Y_lm(mu) exactly, with
    # A_l = I_{l+1/2}(kappa) / I_{1/2}(kappa) ~ exp(-l(l+1) / (2 kappa)) for large kappa
    from scipy.special import ive

    kappa = 200.0
    mu = torch.nn.functional.normalize(torch.tensor([0.3, -0.4, 0.8], dtype=torch.float64), dim=0)
    r = math.sqrt(1 / kappa)
    # vMF expectation by 1-D quadrature in t = cos(angle to mu) (zonal average)
    t, w = np.polynomial.legendre.leggauss(400)
    pdf = kappa / (2 * math.sinh(kappa)) * np.exp(kappa * t)  # density in t (times 2 pi / 2 pi)
    for l in (1, 2, 4, 8):
        P = np.polynomial.legendre.Legendre.basis(l)(t)
        a_exact = float(np.sum(w * pdf * P))
        a_bessel = ive(l + 0.5, kappa) / ive(0.5, kappa)
        assert abs(a_exact - a_bessel) < 1e-8
        e = ide(mu[None], torch.tensor([[r]], dtype=torch.float64))
        e0 = ide(mu[None], torch.zeros(1, 1, dtype=torch.float64))
        k = {1: 0, 2: 2, 4: 5, 8: 10}[l]
        ratio = (e[0, k] / e0[0, k]).item()
        assert abs(ratio - a_exact) < 0.02 * l, (l, ratio, a_exact)
