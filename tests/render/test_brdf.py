"""Tests of voxnero/render/brdf.py (the summed BRDF: reciprocity, formula, lower hemisphere,
gradients, extremes) against closed forms, quadrature and finite differences."""

from __future__ import annotations

import math

import torch
from hypothesis import example, given, settings
from hypothesis import strategies as st

from voxnero.render.brdf import brdf_eval
from voxnero.render.microfacet import (
    ALPHA_MIN,
)
from voxnero.render.splitsum import integrate_ab


def _sph(theta, phi):
    return torch.stack([torch.sin(theta) * torch.cos(phi), torch.sin(theta) * torch.sin(phi),
                        torch.cos(theta)], -1)


def _hemisphere(n_th: int, n_ph: int):
    """Midpoint quadrature of the upper hemisphere (float64): directions ``l (N, 3)``, the
    normal ``n (N, 3)`` = +z, solid-angle weights ``dw (N,)``."""
    th = (torch.arange(n_th, dtype=torch.float64) + 0.5) * (math.pi / 2) / n_th
    ph = (torch.arange(n_ph, dtype=torch.float64) + 0.5) * 2 * math.pi / n_ph
    T, P = torch.meshgrid(th, ph, indexing="ij")
    l = _sph(T.reshape(-1), P.reshape(-1))
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(l.shape[0], 3)
    dw = (torch.sin(T) * (math.pi / 2) / n_th * 2 * math.pi / n_ph).reshape(-1)
    return l, n, dw


def test_brdf_reciprocity_and_formula():
    g = torch.Generator().manual_seed(1)
    N = 1000
    n = torch.tensor([0.0, 0.0, 1.0]).expand(N, 3)
    v = _sph(torch.rand(N, generator=g) * 1.5, torch.rand(N, generator=g) * 6.28)
    l = _sph(torch.rand(N, generator=g) * 1.5, torch.rand(N, generator=g) * 6.28)
    alb = torch.rand(N, 3, generator=g)
    m = torch.rand(N, 1, generator=g)
    r = torch.rand(N, 1, generator=g)
    f = brdf_eval(n, v, l, alb, m, r)
    assert torch.allclose(f, brdf_eval(n, l, v, alb, m, r), rtol=1e-5, atol=1e-6)
    # direct textbook formula in float64 (on 40 of the points: the energy weight's quadrature
    # below is slow)
    K = 40
    f, n, v, l, alb, m, r = f[:K], n[:K], v[:K], l[:K], alb[:K], m[:K], r[:K]
    nd, vd, ld = n.double(), v.double(), l.double()
    h = (vd + ld) / (vd + ld).norm(dim=-1, keepdim=True)
    a = (r.double() ** 2).clamp_min(ALPHA_MIN)
    nh, nv, nl, vh = h[:, 2:], vd[:, 2:], ld[:, 2:], (vd * h).sum(-1, keepdim=True)
    D = a**2 / (math.pi * (nh**2 * (a**2 - 1) + 1) ** 2)

    def g1(c):
        return 2 * c / (c + torch.sqrt(a**2 + (1 - a**2) * c**2))

    F0 = 0.04 * (1 - m.double()) + m.double() * alb.double()
    F = F0 + (1 - F0) * (1 - vh) ** 5
    # energy weight of the diffuse lobe from an independent float64 quadrature of E_d
    def e_d(c, rr):
        A, B = integrate_ab(c[:, 0].clamp_min(1e-4), rr[:, 0].double(), n_samples=2048)
        return (0.04 * A + B)[:, None]

    mu = torch.linspace(0, 1, 65, dtype=torch.float64)[1:]
    e_avg = torch.stack([2 * (e_d(mu[:, None], torch.full((64, 1), float(ri))) * mu[:, None])
                         .mean() for ri in r[:, 0]])[:, None]
    w = (1 - e_d(nv, r)) * (1 - e_d(nl, r)) / (1 - e_avg)
    ref = (1 - m.double()) * w * alb.double() / math.pi + D * g1(nv) * g1(nl) * F / (4 * nv * nl)
    assert torch.allclose(f.double(), ref, rtol=5e-3, atol=1e-4)
    assert nd.shape == (K, 3)


def test_brdf_lower_hemisphere_is_zero():
    n = torch.tensor([[0.0, 0.0, 1.0]])
    up = torch.tensor([[0.0, 0.6, 0.8]])
    down = torch.tensor([[0.0, 0.6, -0.8]])
    args = (torch.ones(1, 3), torch.zeros(1, 1), torch.full((1, 1), 0.5))
    assert (brdf_eval(n, up, down, *args) == 0).all()
    assert (brdf_eval(n, down, up, *args) == 0).all()
    assert (brdf_eval(n, up, up, *args) > 0).all()


def test_brdf_gradients_match_finite_differences():
    g = torch.Generator().manual_seed(2)
    N = 16
    n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand(N, 3)
    v = _sph(torch.rand(N, generator=g, dtype=torch.float64) * 1.2,
             torch.zeros(N, dtype=torch.float64))
    l = _sph(torch.rand(N, generator=g, dtype=torch.float64) * 1.2,
             torch.rand(N, generator=g, dtype=torch.float64) * 6)
    alb = torch.rand(N, 3, generator=g, dtype=torch.float64).requires_grad_()
    m = (0.1 + 0.8 * torch.rand(N, 1, generator=g, dtype=torch.float64)).requires_grad_()
    r = (0.2 + 0.7 * torch.rand(N, 1, generator=g, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda a, mm, rr: brdf_eval(n, v, l, a, mm, rr), (alb, m, r))


unit_f = st.floats(-1.0, 1.0, allow_nan=False)
vec = st.tuples(unit_f, unit_f, unit_f)


@settings(max_examples=150, deadline=None)
@given(n=vec, v=vec, l=vec, r=st.sampled_from([0.0, 1e-6, 0.03, 0.5, 1.0]),
       m=st.sampled_from([0.0, 0.5, 1.0]), scale=st.sampled_from([0.0, 1e-6, 1.0, 3.0]))
def test_brdf_extremes_finite_values_and_grads(n, v, l, r, m, scale):
    t = [torch.tensor([x], dtype=torch.float32, requires_grad=True) for x in (n, v, l)]
    tn, tv, tl = t[0], t[1] * scale, t[2]
    alb = torch.ones(1, 3, requires_grad=True)
    mm = torch.tensor([[m]], requires_grad=True)
    rr = torch.tensor([[r]], requires_grad=True)
    f = brdf_eval(tn, tv, tl, alb, mm, rr) * 1e5
    assert torch.isfinite(f).all()
    f.sum().backward()
    for x in (*t, alb, mm, rr):
        assert torch.isfinite(x.grad).all()


def test_brdf_grazing_exact_cases():
    # n.v exactly 0, 1e-6, 1 and negative, with mirror roughness: finite, >= 0
    n = torch.tensor([[0.0, 0.0, 1.0]]).expand(4, 3)
    v = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 1e-6], [0.0, 0.0, 1.0], [0.6, 0.0, -0.8]])
    l = torch.tensor([[-1.0, 0.0, 0.0], [-1.0, 0.0, 1e-6], [0.0, 0.0, 1.0], [-0.6, 0.0, 0.8]])
    for r in (0.0, 1.0):
        f = brdf_eval(n, v, l, torch.ones(4, 3), torch.ones(4, 1), torch.full((4, 1), r))
        assert torch.isfinite(f).all() and (f >= 0).all()
        assert (f[0] == 0).all() and (f[3] == 0).all()


# -- the principled (Disney 2015) diffuse lobe -------------------------------------------------


def _diffuse_part(n, v, l, r, diffuse):
    """The diffuse lobe alone: albedo 1 minus albedo 0 (a dielectric's F0 is 0.04 either way)."""
    N = n.shape[0]
    m = torch.zeros(N, 1, dtype=n.dtype)
    one, zero = torch.ones(N, 3, dtype=n.dtype), torch.zeros(N, 3, dtype=n.dtype)
    return (brdf_eval(n, v, l, one, m, r, diffuse) - brdf_eval(n, v, l, zero, m, r, diffuse))


@settings(max_examples=60, deadline=None)
@given(r=st.floats(0.0, 1.0), tv=st.floats(0.0, 1.5), tl=st.floats(0.0, 1.5),
       pv=st.floats(0.0, 6.28), pl=st.floats(0.0, 6.28))
def test_principled_diffuse_formula_and_reciprocity(r, tv, tl, pv, pl):
    n = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    v = _sph(torch.tensor([tv], dtype=torch.float64), torch.tensor([pv], dtype=torch.float64))
    l = _sph(torch.tensor([tl], dtype=torch.float64), torch.tensor([pl], dtype=torch.float64))
    rr = torch.tensor([[r]], dtype=torch.float64)
    f = _diffuse_part(n, v, l, rr, "principled")
    assert torch.allclose(f, _diffuse_part(n, l, v, rr, "principled"), rtol=1e-9, atol=1e-12)
    # Burley 2015 / Mitsuba principled, written out: F_x = (1 - cos)^5, R_r = 2 r cos_d^2
    h = (v + l) / (v + l).norm()
    fv, fl = (1 - math.cos(tv)) ** 5, (1 - math.cos(tl)) ** 5
    rr_ = 2 * r * float((l * h).sum()) ** 2
    w = (1 - fl / 2) * (1 - fv / 2) + rr_ * (fl + fv + fl * fv * (rr_ - 1))
    assert math.isclose(float(f[0, 0]), w / math.pi, rel_tol=1e-6, abs_tol=1e-12)


def test_principled_diffuse_albedo_at_normal_view_closed_form():
    # v = n: l.h = cos(theta_l / 2), so R_r = r (1 + mu) and the cosine integral of W is
    # 1 - 1/42 + 5 r / 84 (Beta integrals of (1 - mu)^5 mu^k); the weighted lobe's is 1 - E_d(1)
    l, n, dw = _hemisphere(400, 8)
    N = l.shape[0]
    for r in (0.0, 0.3, 1.0):
        rr = torch.full((N, 1), r, dtype=torch.float64)
        f = _diffuse_part(n, n, l, rr, "principled")[:, 0]
        albedo = float((f * l[:, 2] * dw).sum())
        assert math.isclose(albedo, 1 - 1 / 42 + 5 * r / 84, rel_tol=2e-4), (r, albedo)


@settings(max_examples=25, deadline=None)
@given(r=st.floats(0.0, 1.0), tv=st.floats(0.0, math.pi / 2))
@example(r=1.0, tv=1.56)  # rough and grazing: where every term of the closed form is largest
@example(r=0.0, tv=1.56)
def test_principled_diffuse_albedo_closed_form_matches_quadrature(r, tv):
    # the closed form of the directional albedo (stage 1's split-sum factor) against a
    # midpoint quadrature of the written BRDF over the light hemisphere, any view incl. grazing
    from voxnero.render.brdf import principled_diffuse_albedo

    if math.cos(tv) < 1e-3:  # brdf_eval is zero at n.v = 0; the closed form is continuous there
        return
    l, n, dw = _hemisphere(200, 64)
    N = l.shape[0]
    v = _sph(torch.tensor([tv], dtype=torch.float64), torch.zeros(1, dtype=torch.float64))
    v = v.expand(N, 3)
    rr = torch.full((N, 1), r, dtype=torch.float64)
    f = _diffuse_part(n, v, l, rr, "principled")[:, 0]
    albedo = float((f * l[:, 2] * dw).sum())
    closed = float(principled_diffuse_albedo(torch.tensor([[math.cos(tv)]], dtype=torch.float64),
                                             torch.tensor([[r]], dtype=torch.float64)))
    # the quadrature itself is good to ~1.5e-5 here
    assert math.isclose(closed, albedo, rel_tol=1e-4), (r, tv, closed, albedo)


def test_principled_diffuse_albedo_is_brighter_at_grazing_than_the_weighted_lobe():
    # the reason stage 1 may shade with it: at n.v = 0.1 the photos' (Disney) diffuse is
    # 1.9x (r = 0.1) to 1.4x (r = 0.9) the energy-weighted Lambert's 1 - E_d
    from voxnero.render.brdf import diffuse_weight, principled_diffuse_albedo

    mu = torch.full((3, 1), 0.1)
    r = torch.tensor([[0.1], [0.6], [0.9]])
    ratio = principled_diffuse_albedo(mu, r) / diffuse_weight(mu, r)
    assert (ratio > 1.2).all() and (ratio < 2.0).all(), ratio
    g = torch.zeros(1, 1, requires_grad=True)
    principled_diffuse_albedo(g, g).sum().backward()
    assert torch.isfinite(g.grad).all()


def test_unknown_diffuse_model_is_a_config_error():
    import pytest

    from voxnero.errors import ConfigError
    from voxnero.render.brdf import check_diffuse

    assert check_diffuse("principled") == "principled"
    with pytest.raises(ConfigError, match="diffuse"):
        check_diffuse("lambert")
