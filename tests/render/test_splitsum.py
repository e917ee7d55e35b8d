"""Tests of voxnero/render/splitsum.py against an independent quadrature of the GGX lobe."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.render.microfacet import ALPHA_MIN
from voxnero.render.splitsum import (
    get_table,
    hammersley,
    specular_split_sum,
    split_sum_lookup,
)


def _quadrature_ab(nv: float, r: float, ns: int = 192, nphi: int = 192) -> tuple[float, float]:
    """A, B by a deterministic float64 quadrature in half-vector space.

    h is parametrised by (s, phi) with tan^2(theta_h) = alpha^2 s / (1 - s), whose Jacobian is
    1 / (D(h) cos(theta_h)); the integrand of E = int f_spec (n.l) dl becomes
    G(v, l) F (v.h) / (n.v cos(theta_h)) (written out here from the textbook formulas, not from
    the package: separable Smith G1 = 2c / (c + sqrt(a^2 + (1 - a^2) c^2))). The 1/sqrt(1 - s)
    end-point singularity is removed by s = 1 - t^2 (weight 2t).
    """
    a = max(r * r, ALPHA_MIN)
    t = (torch.arange(ns, dtype=torch.float64) + 0.5) / ns
    s = 1 - t * t
    phi = (torch.arange(nphi, dtype=torch.float64) + 0.5) / nphi * 2 * math.pi
    S, P = torch.meshgrid(s, phi, indexing="ij")
    tan2 = a * a * S / (1 - S)
    ct = 1 / torch.sqrt(1 + tan2)
    st_ = torch.sqrt(1 - ct * ct)
    h = torch.stack([st_ * torch.cos(P), st_ * torch.sin(P), ct], -1)
    v = torch.tensor([math.sqrt(1 - nv * nv), 0.0, nv], dtype=torch.float64)
    vh = (h * v).sum(-1)
    l = 2 * vh[..., None] * h - v
    nl = l[..., 2]

    def g1(c):
        c = c.clamp_min(0)
        return 2 * c / (c + torch.sqrt(a * a + (1 - a * a) * c * c))

    ok = (nl > 0) & (vh > 0)
    w = torch.where(ok, g1(torch.tensor(nv)) * g1(nl) * vh / (nv * ct), torch.zeros_like(nl))
    w = w * 2 * t[:, None]
    fc = (1 - vh.clamp(0, 1)) ** 5
    return (w * (1 - fc)).mean().item(), (w * fc).mean().item()


def test_table_matches_independent_quadrature():
    g = torch.Generator().manual_seed(3)
    pts = torch.rand(24, 2, generator=g, dtype=torch.float64)
    pts[:, 0] = pts[:, 0].clamp_min(0.02)  # the quadrature itself needs n.v > 0
    pts = torch.cat([pts, torch.tensor([[1.0, 0.0], [1.0, 1.0], [0.05, 0.05], [0.5, 0.2],
                                        [0.02, 1.0], [0.9, 0.03]], dtype=torch.float64)])
    A, B = split_sum_lookup(pts[:, 0].float(), pts[:, 1].float())
    for k, (nv, r) in enumerate(pts.tolist()):
        qa, qb = _quadrature_ab(nv, r)
        assert abs(A[k].item() - qa) < 1e-3, (nv, r, A[k].item(), qa)
        assert abs(B[k].item() - qb) < 1e-3, (nv, r, B[k].item(), qb)


def test_white_furnace_metal_never_gains_energy():
    # F0 = 1: directional albedo A + B of the specular lobe alone never exceeds 1
    T = get_table()
    E = T.sum(-1)
    assert E.max().item() <= 1.0 + 2e-4
    # and it loses energy at high roughness (single scattering): normal incidence, r = 1
    A, B = split_sum_lookup(torch.tensor([1.0, 1.0, 1.0]), torch.tensor([0.0, 0.5, 1.0]))
    e = (A + B).tolist()
    assert e[0] > 0.995 and e[1] < 0.95
    # closed form at alpha = 1, n.v = 1: D = 1/pi, G1(v) = 1, so E = (1/4pi) int G1(l) dl
    # = (1/4pi) 2pi int_0^1 2c / (1 + c) dc = 1 - ln 2
    assert abs(e[2] - (1 - math.log(2))) < 1e-3


def test_specular_split_sum_formula_and_grads():
    f0 = torch.tensor([[0.04, 0.5, 1.0]], requires_grad=True)
    nv = torch.tensor([[0.7]], requires_grad=True)
    r = torch.tensor([[0.3]], requires_grad=True)
    light = torch.tensor([[2.0, 3.0, 4.0]], requires_grad=True)
    out = specular_split_sum(f0, nv, r, light)
    A, B = split_sum_lookup(nv, r)
    assert torch.allclose(out, light * (f0 * A + B))
    out.sum().backward()
    for t in (f0, nv, r, light):
        assert torch.isfinite(t.grad).all()
    assert nv.grad.abs().item() > 0 and r.grad.abs().item() > 0


def test_lookup_gradient_is_the_bilinear_slope():
    T = get_table()
    R = T.shape[0]
    # inside one cell the lookup is bilinear in (sqrt(n.v), r): check d/dr by finite differences
    nv = torch.tensor([((10.3) / (R - 1)) ** 2], dtype=torch.float64, requires_grad=True)
    r = torch.tensor([(20.4 / (R - 1)) ** 2], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: split_sum_lookup(a, b)[0], (nv, r), eps=1e-7,
                                    atol=1e-5)


@settings(max_examples=100, deadline=None)
@given(nv=st.sampled_from([1.0, 1e-6, 0.0, -0.3, 0.5]), r=st.sampled_from([0.0, 1.0, 1e-7, 0.5]))
def test_lookup_extremes_finite(nv, r):
    a = torch.tensor([nv], requires_grad=True)
    b = torch.tensor([r], requires_grad=True)
    A, B = split_sum_lookup(a, b)
    (A * 1e5 + B * 1e5).sum().backward()
    assert torch.isfinite(A).all() and torch.isfinite(B).all()
    assert torch.isfinite(a.grad).all() and torch.isfinite(b.grad).all()
    assert (A >= 0).all() and (B >= 0).all()


def test_hammersley_is_stratified():
    u = hammersley(1024)
    assert u.shape == (1024, 2) and (u >= 0).all() and (u < 1).all()
    # every 1/32 x 1/32 cell holds exactly one point (a (0, 2)-net property in base 2)
    cells = (u * 32).long()
    idx = cells[:, 0] * 32 + cells[:, 1]
    assert torch.bincount(idx, minlength=1024).max() == 1


@pytest.mark.slow
def test_whole_table_matches_high_sample_mc():
    # every 3rd node against 32768-sample VNDF Monte Carlo (~10x the table's samples)
    from voxnero.render.splitsum import integrate_ab

    T = get_table()
    R = T.shape[0]
    idx = torch.arange(0, R, 3)
    g = torch.linspace(0, 1, R, dtype=torch.float64)[idx]
    nv, r = torch.meshgrid(g * g, g * g, indexing="ij")
    A, B = integrate_ab(nv.reshape(-1), r.reshape(-1), 1 << 15)
    sub = T[idx][:, idx].reshape(-1, 2).double()
    assert (sub[:, 0] - A).abs().max() < 1e-3
    assert (sub[:, 1] - B).abs().max() < 1e-3
