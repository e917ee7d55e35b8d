"""Tests of voxnero/render/mip.py: area resampling, the mip chain, roughness lookups, and the
learnable (stage-1) path through them at extremes."""

from __future__ import annotations

import torch

from tests.fixtures.envmaps import blob_map
from voxnero.render.latlong import envmap_lookup, pixel_solid_angles
from voxnero.render.mip import lookup_rough, mip_chain
from voxnero.render.sh import sh9_irradiance, sh9_project


def test_mip_chain_conserves_the_integral():
    img = blob_map(64, 128)
    chain = mip_chain(img)
    assert [c.shape[0] for c in chain] == [64, 32, 16, 8, 4, 2]
    ref = (img * pixel_solid_angles(64, 128, dtype=torch.float64)[..., None]).sum((0, 1))
    for c in chain[1:]:
        tot = (c * pixel_solid_angles(*c.shape[:2], dtype=torch.float64)[..., None]).sum((0, 1))
        assert torch.allclose(tot, ref, rtol=1e-10)


def test_lookup_rough_limits_and_grads():
    img = blob_map(64, 128).requires_grad_()
    chain = mip_chain(img)
    d = torch.nn.functional.normalize(torch.randn(20, 3, dtype=torch.float64), dim=-1)
    r0 = torch.zeros(20, 1, dtype=torch.float64)
    assert torch.allclose(lookup_rough(chain, d, r0), envmap_lookup(img, d))
    r1 = torch.ones(20, 1, dtype=torch.float64)
    assert torch.allclose(lookup_rough(chain, d, r1), envmap_lookup(chain[-1], d))
    r = torch.full((20, 1), 0.4, dtype=torch.float64, requires_grad=True)
    lookup_rough(chain, d, r).sum().backward()
    assert torch.isfinite(img.grad).all() and torch.isfinite(r.grad).all()
    assert r.grad.abs().sum() > 0


def test_learnable_path_extremes_finite_grads():
    # stage 1's path: exp(log map) -> mip chain -> lookup_rough -> split-sum, and SH9 diffuse;
    # poles, zero-length and non-unit directions, roughness 0 / 1 / out of range, n.v <= 0
    from voxnero.render.splitsum import specular_split_sum

    log = torch.randn(32, 64, 3, requires_grad=True)
    img = torch.exp(log) * 1e5
    chain = mip_chain(img)
    d = torch.tensor([[0.0, 0, 1], [0, 0, -1], [0, 0, 0], [1, 0, 1e-7], [3, 4, 0]],
                     requires_grad=True)
    r = torch.tensor([[0.0], [1.0], [1e-9], [0.5], [2.0]], requires_grad=True)
    nv = torch.tensor([[1.0], [0.0], [-1.0], [1e-6], [0.5]], requires_grad=True)
    spec = specular_split_sum(torch.ones(5, 3), nv, r, lookup_rough(chain, d, r))
    diff = sh9_irradiance(sh9_project(img), d)
    (spec.sum() + diff.sum()).backward()
    assert torch.isfinite(spec).all() and torch.isfinite(diff).all()
    for t in (log, d, r, nv):
        assert torch.isfinite(t.grad).all()
