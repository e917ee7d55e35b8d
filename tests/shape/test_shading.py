"""Tests of voxnero/shape/shading.py: reflection geometry and limits of the split-sum shading."""

from __future__ import annotations

import torch

from voxnero.render.splitsum import split_sum_lookup
from voxnero.shape.shading import reflect, shade


def test_reflect_mirror_law():
    d = torch.nn.functional.normalize(torch.randn(50, 3), dim=-1)
    n = torch.nn.functional.normalize(torch.randn(50, 3), dim=-1)
    r = reflect(d, n)
    assert torch.allclose(r.norm(dim=-1), torch.ones(50), atol=1e-5)
    # angle of incidence = angle of reflection, and d + r is parallel to... the tangent plane
    assert torch.allclose((r * n).sum(-1), -(d * n).sum(-1), atol=1e-5)
    t = d + r
    assert torch.allclose((t * n).sum(-1), torch.zeros(50), atol=1e-5)


def test_lambert_limit_and_metal_colour():
    n = torch.tensor([[0.0, 0.0, 1.0]])
    d = torch.tensor([[0.0, 0.0, -1.0]])
    alb = torch.tensor([[0.2, 0.5, 0.8]])
    diff = torch.tensor([[1.0, 1.0, 1.0]])
    black = torch.zeros(1, 3)
    rough = torch.tensor([[0.5]])
    # dielectric under diffuse-only light: albedo · L_diff · (1 - E_d), E_d = 0.04 A + B the
    # share the dielectric interface reflects (render/brdf.py); a white furnace gives 1
    c = shade(n, d, alb, torch.zeros(1, 1), rough, black, diff)
    a, b = split_sum_lookup(torch.ones(1, 1), rough)
    assert torch.allclose(c, alb * (1 - (0.04 * a + b)), atol=1e-6)
    assert 0.9 < float((c / alb).mean()) < 0.98
    white = shade(n, d, torch.ones(1, 3), torch.zeros(1, 1), rough, torch.ones(1, 3),
                  torch.ones(1, 3))
    assert torch.allclose(white, torch.ones(1, 3), atol=2e-3)
    # metal: no diffuse; under white specular light the colour follows the albedo (F0 = albedo)
    c = shade(n, d, alb, torch.ones(1, 1), torch.tensor([[0.05]]), torch.ones(1, 3), diff)
    assert torch.allclose(c / c.max(), alb / alb.max(), atol=0.02)
    # a smooth metal facing the viewer reflects about F0 = albedo of the light
    assert torch.allclose(c, alb, atol=0.05)


def test_principled_diffuse_split_sum_under_uniform_light_matches_the_brdf():
    # under uniform light (E(n)/pi = 1) the split-sum shade of the principled lobe is the
    # lobe's directional albedo, which a quadrature of brdf_eval gives independently
    import math

    from voxnero.render.brdf import brdf_eval

    n = torch.tensor([[0.0, 0.0, 1.0]])
    th, ph = torch.meshgrid((torch.arange(160) + 0.5) * (math.pi / 2) / 160,
                            (torch.arange(48) + 0.5) * 2 * math.pi / 48, indexing="ij")
    l = torch.stack([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()], -1).reshape(-1, 3)
    dw = (th.sin() * (math.pi / 2) / 160 * 2 * math.pi / 48).reshape(-1)
    for mu, r in ((1.0, 0.3), (0.3, 0.6), (0.08, 0.1)):
        v = torch.tensor([[math.sqrt(1 - mu * mu), 0.0, mu]])
        rr = torch.tensor([[r]])
        alb = torch.tensor([[0.5, 0.5, 0.5]])
        c = shade(n, -v, alb, torch.zeros(1, 1), rr, torch.zeros(1, 3), torch.ones(1, 3),
                  "principled")
        N = l.shape[0]
        f = (brdf_eval(n.expand(N, 3), v.expand(N, 3), l, alb.expand(N, 3), torch.zeros(N, 1),
                       rr.expand(N, 1), "principled")
             - brdf_eval(n.expand(N, 3), v.expand(N, 3), l, torch.zeros(N, 3),
                         torch.zeros(N, 1), rr.expand(N, 1), "principled"))
        ref = (f[:, 0] * l[:, 2] * dw).sum()
        assert math.isclose(float(c[0, 0]), float(ref), rel_tol=3e-3), (mu, r, c, ref)
    # and the weighted lobe stays the default
    c0 = shade(n, -n, alb, torch.zeros(1, 1), rr, torch.zeros(1, 3), torch.ones(1, 3))
    cw = shade(n, -n, alb, torch.zeros(1, 1), rr, torch.zeros(1, 3), torch.ones(1, 3),
               "weighted")
    assert torch.equal(c0, cw)


def test_material_head_starts_at_the_configured_roughness():
    """``light.init_roughness`` reaches the stage-1 material head: before training, every
    point reads that roughness (the knob of docs/STAGE1.md finding 14)."""
    from voxnero.config import from_dict
    from voxnero.shape.config import ShapeConfig
    from voxnero.shape.renderer import ShapeModel, Switches

    for r0 in (0.1, 0.4, 0.9):
        cfg = from_dict(ShapeConfig, {"grid": {"res": [16], "upsample_at": []},
                                      "light": {"init_roughness": r0}})
        model = ShapeModel(cfg, Switches())
        pts = torch.rand(64, 3) * 1.6 - 0.8
        with torch.no_grad():
            _, _, rough = model.material(model.feat(pts))
        assert torch.allclose(rough, torch.full_like(rough, r0), atol=0.03), (r0, rough.mean())
