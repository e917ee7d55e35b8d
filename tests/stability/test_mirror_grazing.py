"""Roughness-0 mirrors and grazing views, stage 1 (split-sum) and stage 2 (Monte Carlo).

Checked against: the law of reflection (a bright env spot in a known direction L must appear at
the surface point whose analytic sphere normal reflects the view ray into L), energy
conservation (a white metal mirror under a unit env map returns ≤ 1, the white furnace) and
IEEE finiteness of colours and of gradients w.r.t. normals, view directions, material and env
map, for n·v = 0, 1e-6 and slightly negative (−1e-3), and for rays exactly tangent to the
sphere in the stage-1 renderer.
"""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.stability.stability_helpers import (
    S_SCHEDULED_MAX,
    assert_finite_grads,
    set_env,
    spot_env,
    tiny_model,
    tiny_shape_config,
)
from voxnero.fields.lights import EnvLight
from voxnero.material.render import Strategies, env_sampler
from voxnero.material.render import shade as shade_mc
from voxnero.shape.renderer import render_rays
from voxnero.shape.shading import reflect
from voxnero.shape.shading import shade as shade_splitsum

L_SPOT = torch.nn.functional.normalize(torch.tensor([0.35, -0.25, 1.0]), dim=0)
"""Direction of the bright env spot (toward the environment, +Z up)."""
GRAZING = (0.0, 1e-6, -1e-3)
"""n·v of the grazing views: tangent, barely above, slightly below the horizon."""


def _finite(*ts: torch.Tensor) -> bool:
    return all(bool(torch.isfinite(t).all()) for t in ts)


def _view_at(n: torch.Tensor, nv: float, seed: int = 0) -> torch.Tensor:
    """Unit directions ``(N, 3)`` toward the viewer with ``n·v = nv`` (random tangent part)."""
    g = torch.Generator().manual_seed(seed)
    t = torch.linalg.cross(n, torch.randn(n.shape, generator=g), dim=-1)
    t = torch.nn.functional.normalize(t, dim=-1)
    return math.sqrt(1.0 - nv * nv) * t + nv * n


# ------------------------------------------------------------------------------- stage 1

@settings(max_examples=60, deadline=None)
@given(st.one_of(st.sampled_from(GRAZING), st.floats(-0.01, 1.0)),
       st.sampled_from([0.0, 1e-8, 1e-3]), st.sampled_from([0.0, 1.0]))
def test_splitsum_mirror_and_grazing_finite(nv, rough, metal):
    """Stage-1 shading at r ≈ 0 for any n·v (incl. 0, 1e-6, < 0): finite colour and finite
    gradients w.r.t. normal, ray direction, material and the learnable env map."""
    env = EnvLight(16, 0.5)
    with torch.no_grad():
        env.log_radiance.normal_(0.0, 1.0, generator=torch.Generator().manual_seed(1))
    n0 = torch.nn.functional.normalize(torch.randn(8, 3, generator=torch.Generator()
                                                   .manual_seed(2)), dim=-1)
    n = n0.clone().requires_grad_(True)
    d = (-_view_at(n0, nv)).requires_grad_(True)  # camera → surface
    albedo = torch.full((8, 3), 0.8, requires_grad=True)
    metallic = torch.full((8, 1), metal, requires_grad=True)
    r = torch.full((8, 1), rough, requires_grad=True)
    env.prepare()
    refl = reflect(d, n)
    c = shade_splitsum(n, d, albedo, metallic, r, env.specular(refl, r), env.diffuse(n))
    (c * torch.linspace(0.5, 1.5, 8)[:, None]).sum().backward()
    env.release()
    assert _finite(c, n.grad, d.grad, albedo.grad, metallic.grad, r.grad)
    assert assert_finite_grads(env) == 1
    assert (c >= 0).all()


def test_splitsum_mirror_white_furnace():
    """White metal mirror under a unit env: outgoing radiance F0·A + B ≤ 1 at every n·v
    (grazing included), and ≈ 1 (Fresnel → 1) — no blow-up from the 1/n·v of the BRDF."""
    n = torch.nn.functional.normalize(torch.randn(64, 3, generator=torch.Generator()
                                                  .manual_seed(3)), dim=-1)
    for nv in (*GRAZING, 0.5, 1.0):
        d = -_view_at(n, nv)
        one = torch.ones(64, 3)
        c = shade_splitsum(n, d, one, torch.ones(64, 1), torch.zeros(64, 1), one, one)
        assert _finite(c)
        assert (c <= 1.0 + 1e-4).all() and (c >= 0.9).all(), (nv, c.min(), c.max())


def _mirror_sphere_rays(k: int = 48, r0: float = 0.7):
    """Rays straight down (−Z) over a k×k grid covering the sphere of radius r0, and the
    analytic reflected direction of those that hit it (exact sphere normal)."""
    x = torch.linspace(-r0, r0, k)
    gx, gy = torch.meshgrid(x, x, indexing="xy")
    o = torch.stack([gx.reshape(-1), gy.reshape(-1), torch.full((k * k,), 3.0)], -1)
    d = torch.tensor([0.0, 0.0, -1.0]).expand(k * k, 3).contiguous()
    rho2 = gx.reshape(-1) ** 2 + gy.reshape(-1) ** 2
    inside = rho2 < (0.97 * r0) ** 2
    p = torch.stack([o[:, 0], o[:, 1], (r0 ** 2 - rho2).clamp_min(0).sqrt()], -1)
    n = torch.nn.functional.normalize(p, dim=-1)
    return o, d, inside, d - 2 * (d * n).sum(-1, keepdim=True) * n


def _angle_deg(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(torch.acos((a * b).sum(-1).clamp(-1, 1)))


def test_stage1_mirror_reflection_lands_by_the_law():
    """Stage-1 renderer, mirror metal (r = 0) on the initial sphere SDF (r = 0.7, 48³ grid),
    env = dim + bright spot at L: the brightest hit ray is the one whose analytic reflection
    points at L within 5° (64² rays: ≈ 2.5° of reflection angle apart there; the 48³ grid's
    trilinear normals are ≈ 1.1° off the exact sphere's (median), 2.2° after reflection; a
    mirrored env mapping or a wrong reflection formula lands ≥ 35° away), and rays reflecting
    > 30° away from L see only the dim env; gradients finite at r = 0."""
    cfg = tiny_shape_config(grid={"res": [48]}, light={"env_height": 64})
    m = tiny_model(cfg, material=(1.0, 1.0, 0.0))
    set_env(m, spot_env(64, L_SPOT, base=0.01, peak=50.0, width_deg=5.0))
    o, d, inside, refl_true = _mirror_sphere_rays(64, cfg.grid.init_radius)
    m.env.prepare()
    out = render_rays(m, o, d, S_SCHEDULED_MAX, cfg, train=False)
    out["rgb"][inside].mean().backward()
    m.env.release()
    lum = out["rgb"].detach().mean(-1)
    lum = torch.where(inside, lum, torch.zeros_like(lum))
    ang = _angle_deg(refl_true, L_SPOT)
    best = int(lum.argmax())
    assert float(ang[best]) < 5.0, (float(ang[best]), float(ang[inside].min()))
    assert float(lum[best]) > 20.0
    far = inside & (ang > 30.0)
    assert float(lum[far].max()) < 0.05
    assert _finite(out["rgb"], out["normal"])
    assert assert_finite_grads(m, "mirror") >= 3


@pytest.mark.parametrize("eps", [0.0, 1e-6, -1e-3, 1e-3])
@pytest.mark.parametrize("radius_of", ["object", "bound"])
@pytest.mark.parametrize("normals", ["analytic", "fd"])
def test_stage1_renderer_tangent_rays(eps, radius_of, normals):
    """Rays tangent to the initial sphere SDF (impact parameter r0·(1 − eps)) and to the
    sampling bound (radius 1: near = far, zero-length intervals), analytic and
    finite-difference SDF normals: finite colour, accumulated opacity in [0, 1], normals unit
    or zero (never NaN) and finite gradients of every parameter."""
    cfg = tiny_shape_config(grid={"normals": normals})
    m = tiny_model(cfg)
    r0 = cfg.grid.init_radius if radius_of == "object" else cfg.sampling.radius
    b = r0 * (1.0 - eps)
    az = torch.linspace(0, 2 * math.pi, 9)[:-1]
    o = torch.stack([b * torch.cos(az), b * torch.sin(az), torch.full_like(az, -3.0)], -1)
    d = torch.tensor([0.0, 0.0, 1.0]).expand(8, 3).contiguous()
    for train in (True, False):
        m.zero_grad(set_to_none=True)
        m.env.prepare()
        out = render_rays(m, o, d, S_SCHEDULED_MAX, cfg, train=train,
                          generator=torch.Generator().manual_seed(0))
        loss = out["rgb"].sum() + out["normal"].sum() + ((out["grad"].norm(dim=-1) - 1) ** 2
                                                          ).sum()
        loss.backward()
        m.env.release()
        assert _finite(out["rgb"], out["acc"], out["normal"])
        assert (out["acc"] >= 0).all() and (out["acc"] <= 1 + 1e-5).all()
        nn = out["normal"].norm(dim=-1)
        assert ((nn - 1).abs() < 1e-4).logical_or(nn == 0).all(), nn
        assert_finite_grads(m, f"tangent eps={eps} {radius_of} {normals}")


# ------------------------------------------------------------------------------- stage 2

def _mc_points(k: int = 40, radius: float = 0.5, res: int = 96):
    """Stage-2 geometry (UV sphere) and the hits of rays straight down (−Z) on a k×k grid."""
    from tests.material.stage2_scene import sphere_geometry

    geom = sphere_geometry(radius, res)
    o, d, _, _ = _mirror_sphere_rays(k, radius)
    t, tri, bary = geom.cast(o, d)
    ok = torch.isfinite(t)
    tri, bary, o, d, t = tri[ok], bary[ok], o[ok], d[ok], t[ok]
    x = geom.points_at(tri, bary)
    return geom, tri, bary, x, geom.normals_at(tri, bary), d


def _const_field(albedo: float, metallic: float, roughness: float, n: int):
    """A material field ``(tri, bary, x) -> (albedo, metallic, roughness)`` of leaf tensors
    (roughness may be exactly 0, which the sigmoid-parametrised fields cannot reach)."""
    a = torch.full((n, 3), albedo, requires_grad=True)
    m = torch.full((n, 1), metallic, requires_grad=True)
    r = torch.full((n, 1), roughness, requires_grad=True)
    return (lambda tri, bary, x: (a, m, r)), (a, m, r)


def test_stage2_mirror_reflection_lands_by_the_law():
    """Stage-2 MC shading (cosine + GGX + env samples, MIS, visibility on) of a mirror metal
    sphere (r = 0, α clamped at ALPHA_MIN): the brightest point is the one whose analytic
    normal reflects the view ray into L (within 4°), points reflecting > 30° away see only the
    dim env, and all gradients (material at r = 0, env map) are finite."""
    geom, tri, bary, x, n, d = _mc_points()
    field, params = _const_field(1.0, 1.0, 0.0, x.shape[0])
    env = spot_env(64, L_SPOT, base=0.01, peak=50.0, width_deg=5.0).requires_grad_(True)
    L = shade_mc(geom, field, env, tri, bary, x, n, -d, Strategies(8, 8, 8),
                 env=env_sampler(env), generator=torch.Generator().manual_seed(0))
    L.mean().backward()
    assert _finite(L, env.grad, *[p.grad for p in params])
    nt = torch.nn.functional.normalize(x, dim=-1)  # exact sphere normal at the hit
    refl = d - 2 * (d * nt).sum(-1, keepdim=True) * nt
    ang = _angle_deg(refl, L_SPOT)
    lum = L.detach().mean(-1)
    best = int(lum.argmax())
    assert float(ang[best]) < 4.0, (float(ang[best]), float(ang.min()))
    assert float(lum[best]) > 20.0
    assert float(lum[ang > 30.0].max()) < 0.05


@pytest.mark.parametrize("nv", GRAZING)
@pytest.mark.parametrize("rough", [0.0, 0.3])
def test_stage2_grazing_views_finite_and_energy_conserving(nv, rough):
    """Stage-2 MC shading at n·v = 0, 1e-6, −1e-3: finite colour and gradients w.r.t. normals,
    view directions, material and env map; a white metal under a unit env returns ≤ 1 on
    average (white furnace, MC tolerance 3 % at 24 spp), also below the horizon, where the
    shading normal is bent toward the viewer."""
    geom, tri, bary, x, n0, _ = _mc_points(16, res=40)
    k = x.shape[0]
    n = n0.clone().requires_grad_(True)
    v = _view_at(n0, nv).requires_grad_(True)
    field, params = _const_field(1.0, 1.0, rough, k)
    env = torch.ones(16, 32, 3, requires_grad=True)
    L = shade_mc(geom, field, env, tri, bary, x, n, v, Strategies(8, 8, 8),
                 env=env_sampler(env), generator=torch.Generator().manual_seed(1))
    L.sum().backward()
    assert _finite(L, n.grad, v.grad, env.grad, *[p.grad for p in params])
    assert float(L.detach().mean()) <= 1.03, float(L.detach().mean())
    if nv < 0:
        # a shading normal facing away from the viewer is bent to n·v = 1e-3 (material/render.py:
        # silhouettes and secondary hits would turn black): shaded like a grazing view, not 0
        assert float(L.detach().mean()) > 0.5, float(L.detach().mean())
