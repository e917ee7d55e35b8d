"""Lights of stage 2: the env map's start from background pixels, the indirect-light estimate.
(The env light itself, shared with stage 1, is tested in tests/fields/test_lights.py.)"""

from __future__ import annotations

import torch

from voxnero.material.lights import IndirectLight, init_from_background
from voxnero.render.latlong import envmap_lookup, pixel_dirs


def test_init_from_background_recovers_pixel_values_and_fills_the_rest():
    H = 8
    g = torch.Generator().manual_seed(0)
    truth = torch.rand(H, 2 * H, 3, generator=g)
    d = pixel_dirs(H, 2 * H).reshape(-1, 3)
    # the upper part is seen; pole rows are left out (all their columns share one direction)
    up = (d[:, 2] > 0.1) & (d[:, 2] < 0.99)
    img = init_from_background(d[up], truth.reshape(-1, 3)[up], H)
    assert torch.allclose(img.reshape(-1, 3)[up], truth.reshape(-1, 3)[up], atol=1e-5)
    mean = truth.reshape(-1, 3)[up].mean(0)
    low = d[:, 2] <= 0.1
    assert torch.allclose(img.reshape(-1, 3)[low], mean.expand(int(low.sum()), 3), atol=1e-5)


def test_indirect_radiance_in_a_white_furnace():
    """Constant unit env: the estimate is (1 - m)(1 - E_d) a + F0 A + B (split-sum directional
    albedo; E_d = 0.04 A + B is what the dielectric interface reflects)."""
    from voxnero.render.splitsum import split_sum_lookup

    ind = IndirectLight(torch.ones(16, 32, 3))
    n = torch.tensor([[0.0, 0.0, 1.0]] * 2)
    w = torch.nn.functional.normalize(torch.tensor([[0.3, 0.0, 1.0], [0.0, 0.0, -1.0]]), dim=-1)
    a = torch.tensor([[0.5, 0.6, 0.7]] * 2)
    m = torch.tensor([[0.3]] * 2)
    r = torch.tensor([[0.4]] * 2)
    L = ind.radiance(n, w, a, m, r)
    A, B = split_sum_lookup(w[:1, 2], r[:1, 0])
    e_d = 0.04 * A + B
    want = (1 - m[0]) * (1 - e_d) * a[0] + (0.04 * (1 - m[0]) + m[0] * a[0]) * A + B
    assert torch.allclose(L[0], want, rtol=5e-3)
    assert torch.equal(L[1], torch.zeros(3))  # seen from below the surface
    assert torch.allclose(envmap_lookup(ind.blur, w), torch.ones(2, 3))
