"""Near-background field (voxnero/fields/background.py): contraction, sample placement and
compositing against closed forms."""

from __future__ import annotations

import math

import torch

from voxnero.fields.background import (
    NearBackground,
    contract,
    disparity_samples,
    start_depth,
)


def test_contraction_closed_form():
    x = torch.tensor([[0.3, -0.2, 0.1], [2.0, 0.0, 0.0], [0.0, -4.0, 0.0], [1e6, 0.0, 0.0]])
    c = contract(x)
    torch.testing.assert_close(c[0], x[0])  # inside the unit sphere: identity
    torch.testing.assert_close(c[1], torch.tensor([1.5, 0.0, 0.0]))  # 2 - 1/2
    torch.testing.assert_close(c[2], torch.tensor([0.0, -1.75, 0.0]))  # 2 - 1/4
    assert 1.99 < float(c[3].norm()) <= 2.0


def test_start_depth_exit_or_closest_approach():
    o = torch.tensor([[0.0, 0.0, -3.0], [2.0, 0.0, -3.0], [0.0, 0.0, 0.0]])
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    t = start_depth(o, d)
    # through the centre: leaves at z = +1 (t = 4); misses: closest approach at z = 0 (t = 3);
    # from the centre: leaves at t = 1
    torch.testing.assert_close(t, torch.tensor([4.0, 3.0, 1.0]))


def test_disparity_samples_uniform_in_disparity():
    t = disparity_samples(torch.tensor([2.0]), 4, far_ratio=8.0)
    disp = 2.0 / t[0]
    torch.testing.assert_close(disp, torch.linspace(1.0, 1.0 / 8.0, 5))
    tj = disparity_samples(torch.full((100,), 2.0), 4, 8.0, jitter=True)
    assert (tj[:, 1:] > tj[:, :-1]).all() and (tj[:, 0] == 2.0).all()
    torch.testing.assert_close(tj[:, -1], torch.full((100,), 16.0))


def test_constant_density_transmittance_is_exp_of_contracted_length():
    """From the centre outward the contracted radius goes from 1 to 2 - 1/far_ratio, so with a
    constant density sigma the transmittance is exp(-sigma (1 - 1/far_ratio)) exactly."""
    for sigma in (0.3, 2.0):
        f = NearBackground(res=8, samples=12, far_ratio=32.0, init_density=sigma)
        with torch.no_grad():
            f.grid[1:] = 0.0  # colour sigmoid(0) = 0.5
        d = torch.nn.functional.normalize(torch.randn(64, 3), dim=-1)
        rgb, trans = f(torch.zeros(64, 3), d)
        expect = math.exp(-sigma * (1 - 1 / 32.0))
        torch.testing.assert_close(trans, torch.full((64,), expect), rtol=1e-4, atol=1e-5)
        # colour composited: (1 - T) * 0.5
        torch.testing.assert_close(rgb, torch.full((64, 3), 0.5 * (1 - expect)), rtol=1e-4,
                                   atol=1e-5)


def test_gradients_reach_the_grid():
    f = NearBackground(res=8, samples=8)
    o = torch.tensor([[0.0, 0.0, -3.0]]).expand(16, 3)
    d = torch.nn.functional.normalize(torch.randn(16, 3) * 0.2 + torch.tensor([0, 0, 1.0]),
                                      dim=-1)
    rgb, trans = f(o, d, jitter=True)
    (rgb.sum() + trans.sum()).backward()
    assert f.grid.grad is not None and f.grid.grad.abs().sum() > 0
