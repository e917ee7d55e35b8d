"""The coarse, reliability-gated SDF step (voxnero/shape/coarse_step.py) against closed forms."""

from __future__ import annotations

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.shape.coarse_step import CoarseStep


@settings(max_examples=25, deadline=None)
@given(res=st.integers(4, 40), factor=st.integers(1, 12), lr=st.floats(1e-4, 1e-1),
       sign=st.sampled_from([-1.0, 1.0]), scale=st.floats(1e-6, 1e3))
def test_a_gradient_that_keeps_its_sign_moves_every_voxel_by_the_rate(res, factor, lr, sign,
                                                                       scale):
    """A constant gradient: Adam's normalised step is 1 and so is its reliability, so the grid
    moves by exactly ``lr`` per step against the gradient, whatever the grid and block sizes
    and the gradient's magnitude."""
    grid = torch.zeros(1, res, res, res)
    grad = torch.full_like(grid, sign * scale)
    cs = CoarseStep(factor)
    for _ in range(3):
        cs.step(grid, grad, lr)
    torch.testing.assert_close(grid, torch.full_like(grid, -3 * sign * lr), rtol=1e-4,
                               atol=1e-7)


def test_noise_barely_moves_the_grid():
    """A gradient of random sign every step (the block-averaged noise of sparse rays): the gate
    m²/v is about (1 − β₁)/(1 + β₁) ≈ 0.05, so the grid moves far less than a consistent
    gradient moves it (ungated Adam would random-walk by about a quarter of the rate a step)."""
    gen = torch.Generator().manual_seed(0)
    res, lr, n = 16, 1e-2, 200
    grid = torch.zeros(1, res, res, res)
    cs = CoarseStep(4)
    steps = []
    for _ in range(n):
        grad = torch.randn(1, res, res, res, generator=gen)
        steps.append(cs.step(grid, grad, lr).abs().mean())
    late = torch.stack(steps[50:]).mean()  # past Adam's bias-corrected start
    assert late < 0.06 * lr, late
    assert grid.abs().max() < 0.1 * n * lr


def test_a_pulled_block_moves_and_a_far_one_stays():
    """A consistent gradient on one corner block moves that block by the rate; blocks more
    than one block away (outside the trilinear upsampling's reach) do not move."""
    res, k, lr = 32, 4, 1e-2
    grid = torch.zeros(1, res, res, res)
    grad = torch.zeros_like(grid)
    grad[0, :k, :k, :k] = 1.0
    cs = CoarseStep(k)
    cs.step(grid, grad, lr)
    assert torch.isclose(grid[0, 0, 0, 0], torch.tensor(-lr), rtol=1e-4)
    assert grid[0, 3 * k:, 3 * k:, 3 * k:].abs().max() == 0.0


def test_a_new_resolution_starts_new_moments():
    """After an upsampling the moments restart (their shape follows the grid): the first step
    on the new grid is again exactly the rate."""
    cs = CoarseStep(2)
    g8 = torch.zeros(1, 8, 8, 8)
    for _ in range(5):
        cs.step(g8, torch.randn(1, 8, 8, 8), 1e-2)
    g16 = torch.zeros(1, 16, 16, 16)
    cs.step(g16, torch.ones_like(g16), 1e-2)
    torch.testing.assert_close(g16, torch.full_like(g16, -1e-2), rtol=1e-4, atol=1e-7)
    assert cs.t == 1
