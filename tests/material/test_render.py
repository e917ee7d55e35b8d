"""Monte Carlo rendering equation of stage 2 against closed forms and between strategies."""

from __future__ import annotations

import math

import open3d as o3d
import pytest
import torch

from tests.material.stage2_scene import smooth_env, sphere_geometry
from voxnero.material.field import VertexMaterial
from voxnero.material.render import Strategies, env_sampler, sample_directions, shade
from voxnero.material.surface import Geometry
from voxnero.render.splitsum import split_sum_lookup


def _points(geom, n=256, seed=0):
    g = torch.Generator().manual_seed(seed)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    _, tri, bary = geom.cast(3 * d, -d)
    x, nrm = geom.points_at(tri, bary), geom.normals_at(tri, bary)
    v = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    v = torch.where((v * nrm).sum(-1, keepdim=True) < 0, -v, v)
    v = torch.nn.functional.normalize(v + 0.2 * nrm, dim=-1)
    return tri, bary, x, nrm, v


@pytest.mark.parametrize("albedo,metallic,rough", [(1.0, 1.0, 0.3), (0.6, 0.0, 0.5),
                                                    (0.8, 1.0, 0.08), (0.3, 0.5, 0.7)])
def test_white_furnace_matches_split_sum_directional_albedo(albedo, metallic, rough):
    """Constant unit env, convex object: L_o = (1 - m) a (1 - E_d) + F0 A(n.v, r) + B(n.v, r),
    E_d = 0.04 A + B (the diffuse lobe gets what the dielectric interface does not reflect).

    A and B come from the shading core's independently integrated split-sum table (Hammersley,
    4096 samples per node). Tolerances (Monte Carlo, 192 spp): mean |relative error| 1.5 %,
    signed mean (bias) 0.5 %.
    """
    geom = sphere_geometry(0.5, 40)
    tri, bary, x, n, v = _points(geom)
    field = VertexMaterial(geom, albedo, metallic, rough)
    env = torch.ones(16, 32, 3)
    g = torch.Generator().manual_seed(1)
    L = shade(geom, field, env, tri, bary, x, n, v, Strategies(64, 64, 64), env=env_sampler(env),
              generator=g)
    a, m, r = field(tri, bary, x)
    A, B = split_sum_lookup((n * v).sum(-1), r[:, 0])
    f0 = 0.04 * (1 - m) + m * a
    e_d = 0.04 * A[:, None] + B[:, None]
    ref = f0 * A[:, None] + B[:, None] + (1 - m) * a * (1 - e_d)
    assert ((L - ref).abs() / ref).mean() < 0.015
    assert ((L - ref) / ref).mean().abs() < 0.005


def test_strategies_agree_on_a_structured_env_map():
    """Cosine-only, GGX-only, env-only and MIS estimates of the same pixels agree (unbiased)."""
    geom = sphere_geometry(0.5, 40)
    tri, bary, x, n, v = _points(geom, 48)
    field = VertexMaterial(geom, 0.7, 0.5, 0.35)
    env = smooth_env(32)
    samp = env_sampler(env)
    out = {}
    for name, spp in {"cos": Strategies(384, 0, 0), "ggx": Strategies(0, 384, 0),
                      "env": Strategies(0, 0, 384), "mis": Strategies(128, 128, 128)}.items():
        g = torch.Generator().manual_seed(2)
        out[name] = shade(geom, field, env, tri, bary, x, n, v, spp, env=samp, generator=g)
    ref = out["mis"].mean(0)
    for name in ("cos", "ggx", "env"):
        assert torch.allclose(out[name].mean(0), ref, rtol=0.03), name


def test_mis_weights_partition_unity():
    """Sum over strategies of n_k p_k * wop = 1 for each drawn direction (power heuristic)."""
    from voxnero.render.sampling import pdf_cosine, pdf_ggx_vndf

    geom = sphere_geometry(0.5, 20)
    tri, bary, x, n, v = _points(geom, 32)
    alpha = torch.full((32, 1), 0.09)
    env = smooth_env(16)
    samp = env_sampler(env)
    spp = Strategies(3, 5, 4)
    l, wop, counts = sample_directions(n, v, alpha, spp, samp, torch.Generator().manual_seed(0))
    S = l.shape[1]
    nS, vS = n[:, None].expand(-1, S, 3), v[:, None].expand(-1, S, 3)
    q = torch.stack([3 * pdf_cosine(nS, l), 5 * pdf_ggx_vndf(nS.reshape(-1, 3), vS.reshape(-1, 3),
                                                              l.reshape(-1, 3), 0.09).view(32, S),
                     4 * samp.pdf(l)], -1)
    # the estimator's weight of a sample is q_own / sum q^2; the power-heuristic weights of all
    # strategies at that direction sum to one: sum_k q_k^2 / sum q^2 = 1, and wop * q_own = w_own
    w_own = wop * q.gather(-1, torch.tensor([0] * 3 + [1] * 5 + [2] * 4).view(1, S, 1)
                           .expand(32, S, 1))[..., 0]
    w_all = q**2 / (q**2).sum(-1, keepdim=True)
    own = torch.tensor([0] * 3 + [1] * 5 + [2] * 4)
    assert torch.allclose(w_own, w_all.gather(-1, own.view(1, S, 1).expand(32, S, 1))[..., 0],
                          atol=1e-4)
    assert counts == [3, 5, 4]


def test_shadow_of_a_blocker_halves_a_uniform_sky():
    """A point on a floor under an infinite wall... approximated: a Lambertian point at the foot
    of a tall box sees only half of a uniform env's upper hemisphere (irradiance pi/2 of pi).
    """
    floor = o3d.geometry.TriangleMesh.create_box(4, 4, 0.01).translate([-2, -2, -0.01])
    wall = o3d.geometry.TriangleMesh.create_box(0.01, 40, 40).translate([0.02, -20, 0])
    geom = Geometry.from_legacy(floor + wall)
    _, tri, bary = geom.cast(torch.tensor([[0.0, 0.0, 1.0]]), torch.tensor([[0.0, 0.0, -1.0]]))
    x = geom.points_at(tri, bary)
    n = torch.tensor([[0.0, 0.0, 1.0]])
    v = torch.tensor([[-0.6, 0.0, 0.8]])
    # near-diffuse material: albedo 1, metallic 0, rough 1 (specular part small but present)
    geom_field = VertexMaterial(geom, 0.999, 0.0, 1.0)
    env = torch.ones(16, 32, 3)
    g = torch.Generator().manual_seed(3)
    tri_b, bary_b, x_b = tri.expand(64), bary.expand(64, 3), x.expand(64, 3)
    n_b, v_b = n.expand(64, 3), v.expand(64, 3)
    lit = shade(geom, geom_field, env, tri_b, bary_b, x_b, n_b, v_b, Strategies(64, 0, 0),
                visibility=False, generator=g).mean()
    shadowed = shade(geom, geom_field, env, tri_b, bary_b, x_b, n_b, v_b, Strategies(64, 0, 0),
                     visibility=True, generator=g).mean()
    # the wall is at x = 0.02 >> RAY_EPS and 40 high: it hides almost exactly the x > 0 half
    assert math.isclose(float((shadowed / lit).detach()), 0.5, abs_tol=0.03)


@pytest.mark.parametrize("rough", [0.2, 0.8])
def test_white_furnace_with_the_principled_lobe_at_normal_view(rough):
    """``diffuse="principled"`` reaches the estimator through ``shade`` (so through stage 2's
    trainer, evaluation and relighting): a dielectric seen along its normal in a constant unit
    env returns the specular split-sum albedo plus a · (1 − 1/42 + 5 r / 84), the principled
    diffuse lobe's closed-form albedo at normal view, not the energy-weighted a · (1 − E_d).
    Tolerances (Monte Carlo, 192 spp): mean relative error 1.5 %, bias 0.5 %."""
    geom = sphere_geometry(0.5, 40)
    tri, bary, x, n, _ = _points(geom)
    field = VertexMaterial(geom, 0.6, 0.0, rough)
    env = torch.ones(16, 32, 3)
    g = torch.Generator().manual_seed(2)
    L = shade(geom, field, env, tri, bary, x, n, n, Strategies(64, 64, 64), env=env_sampler(env),
              generator=g, diffuse="principled")
    a, m, r = field(tri, bary, x)
    A, B = split_sum_lookup(torch.ones(n.shape[0]), r[:, 0])
    ref = 0.04 * A[:, None] + B[:, None] + a * (1 - 1 / 42 + 5 * r / 84)
    assert ((L - ref).abs() / ref).mean() < 0.015
    assert ((L - ref) / ref).mean().abs() < 0.005
    weighted = shade(geom, field, env, tri, bary, x, n, n, Strategies(64, 64, 64),
                     env=env_sampler(env), generator=torch.Generator().manual_seed(2))
    # the principled lobe is not Fresnel-weighted
    assert float((L / weighted).mean().detach()) > 1.02
