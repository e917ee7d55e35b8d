"""Tests of voxnero/render/sampling.py: histograms against pdfs (chi-square), frames, MIS."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.fixtures.chi2 import (
    chi2_pvalue,
    sampler_pvalue,
    zphi_expected,
    zphi_histogram,
)
from voxnero.render.sampling import (
    balance_heuristic,
    frame_from_normal,
    pdf_cosine,
    pdf_ggx_vndf,
    power_heuristic,
    sample_cosine,
    sample_ggx_vndf,
)


def test_cosine_sampler_histogram_matches_pdf():
    n = torch.nn.functional.normalize(torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64), dim=0)
    p = sampler_pvalue(lambda u: sample_cosine(u, n.expand(u.shape[0], 3)),
                       lambda w: pdf_cosine(n.expand_as(w), w), n, zmin=0.0)
    assert p > 1e-3
    # closed form: E[n.l] = 2/3 for the cosine distribution
    g = torch.Generator().manual_seed(0)
    N = 100_000
    l, _ = sample_cosine(torch.rand(N, 2, generator=g, dtype=torch.float64), n.expand(N, 3))
    assert abs((l @ n).mean().item() - 2 / 3) < 5e-3


@pytest.mark.parametrize("alpha,theta_v", [(0.3, 0.6), (0.7, 1.2), (0.1, 0.2), (1.0, 1.5)])
def test_ggx_vndf_histogram_matches_pdf(alpha, theta_v):
    g = torch.Generator().manual_seed(1)
    N = 100_000
    n = torch.nn.functional.normalize(torch.tensor([-0.2, 0.4, -0.9], dtype=torch.float64), dim=0)
    t, b = frame_from_normal(n[None])
    v = (math.sin(theta_v) * t + math.cos(theta_v) * n[None])[0]
    nn_, vv = n.expand(N, 3), v.expand(N, 3)
    l, pdf = sample_ggx_vndf(torch.rand(N, 2, generator=g, dtype=torch.float64), nn_, vv, alpha)
    assert torch.allclose(pdf, pdf_ggx_vndf(nn_, vv, l, alpha), rtol=1e-6)
    sub = 16
    exp = N * zphi_expected(lambda w: pdf_ggx_vndf(n.expand_as(w), v.expand_as(w), w, alpha),
                            n, sub=sub)
    # the pdf integrates to 1 over the sphere (samples below the horizon included); the
    # midpoint quadrature converges slowly at the wedge where the support pinches (l = -v)
    assert abs(exp.sum() / N - 1) < 5e-3
    assert chi2_pvalue(zphi_histogram(l, nn_), exp) > 1e-3


def test_ggx_vndf_mirror_limit_and_grazing():
    N = 1000
    n = torch.tensor([[0.0, 0.0, 1.0]]).expand(N, 3)
    v = torch.tensor([[0.6, 0.0, 0.8]]).expand(N, 3)
    u = torch.rand(N, 2)
    l, pdf = sample_ggx_vndf(u, n, v, 1e-3)
    refl = torch.tensor([-0.6, 0.0, 0.8])
    # GGX's heavy tail: the median half-vector tilt is ~alpha, the reflected one ~2 alpha
    dev = (l - refl).norm(dim=-1)
    assert dev.median() < 4e-3 and (dev < 0.05).float().mean() > 0.99
    assert torch.isfinite(pdf).all()
    for vz in (0.0, 1e-6, -0.5):
        vv = torch.nn.functional.normalize(torch.tensor([[1.0, 0.0, vz]]), dim=-1).expand(N, 3)
        l, pdf = sample_ggx_vndf(u, n, vv, 0.5)
        assert torch.isfinite(l).all() and torch.isfinite(pdf).all() and (pdf >= 0).all()


@settings(max_examples=200, deadline=None)
@given(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)))
def test_frame_from_normal_orthonormal(nv):
    n = torch.tensor([nv], dtype=torch.float64)
    if n.norm() < 1e-6:
        n = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    n = n / n.norm()
    t, b = frame_from_normal(n)
    m = torch.cat([t, b, n], 0)
    assert torch.allclose(m @ m.T, torch.eye(3, dtype=torch.float64), atol=1e-9)
    assert torch.allclose(torch.linalg.cross(t, b), n, atol=1e-9)


def test_frame_exact_poles():
    for z in (1.0, -1.0):
        n = torch.tensor([[0.0, 0.0, z]])
        t, b = frame_from_normal(n)
        assert torch.isfinite(t).all() and abs((t * b).sum().item()) < 1e-7


def test_mis_heuristics():
    p = torch.tensor([[1.0, 3.0], [0.0, 0.0], [2.0, 0.0], [1e30, 1e30]])
    w = power_heuristic(p)
    assert torch.allclose(w[0], torch.tensor([0.1, 0.9]))
    assert torch.allclose(w[1], torch.tensor([0.5, 0.5]))
    assert torch.allclose(w[2], torch.tensor([1.0, 0.0]))
    assert torch.allclose(w[3], torch.tensor([0.5, 0.5]))
    wb = balance_heuristic(p[:1], counts=[2, 1])
    assert torch.allclose(wb, torch.tensor([[0.4, 0.6]]))
