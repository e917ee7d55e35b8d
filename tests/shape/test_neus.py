"""Tests of voxnero/shape/neus.py: closed forms of the logistic CDF, unbiasedness, compositing."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.shape.neus import (
    alpha_from_interval,
    alpha_from_samples,
    alpha_from_sdf_sequence,
    alpha_from_sequence_min,
    composite_weights,
    sharpness_schedule,
)


@settings(max_examples=50, deadline=None)
@given(st.floats(-1, 1), st.floats(-1, 1), st.floats(1, 30))
def test_alpha_closed_form(a, b, s):
    sig = lambda x: 1 / (1 + math.exp(-x))  # noqa: E731
    expected = min(max((sig(s * a) - sig(s * b)) / max(sig(s * a), 1e-300), 0.0), 1.0)
    got = float(alpha_from_interval(torch.tensor(a, dtype=torch.float64),
                                    torch.tensor(b, dtype=torch.float64), s))
    assert abs(got - expected) < 1e-9
    assert 0.0 <= got <= 1.0


def test_plane_weights_peak_at_crossing_and_sum_to_one():
    # ray along +z through the plane z = 0.3 (sdf = 0.3 − z along the ray: entering)
    z = torch.linspace(0, 1, 2001, dtype=torch.float64)[None]
    sdf = 0.3 - z
    dist = torch.full_like(z, 1 / 2000)
    w = composite_weights(alpha_from_samples(sdf, -torch.ones_like(z), dist, 200.0))
    assert abs(float(w.sum()) - 1.0) < 1e-3
    peak = float(z[0, w.argmax()])
    assert abs(peak - 0.3) < 1e-3
    mean = float((w * z).sum() / w.sum())
    assert abs(mean - 0.3) < 2e-3


def test_exit_side_gets_no_opacity():
    z = torch.linspace(0, 1, 101)[None]
    sdf = z - 0.5  # leaving the surface
    a = alpha_from_samples(sdf, torch.ones_like(z), torch.full_like(z, 0.01), 100.0)
    assert float(a.max()) == 0.0


def test_composite_weights_transmittance():
    alpha = torch.tensor([[0.5, 0.5, 1.0, 0.3]])
    w = composite_weights(alpha)
    assert torch.allclose(w, torch.tensor([[0.5, 0.25, 0.25, 0.0]]), atol=1e-5)


def test_sharpness_schedule_geometric():
    assert abs(sharpness_schedule(0, 30, 300) - 30) < 1e-9
    assert abs(sharpness_schedule(1, 30, 300) - 300) < 1e-9
    assert abs(sharpness_schedule(0.5, 30, 300) - math.sqrt(30 * 300)) < 1e-9
    assert abs(sharpness_schedule(2, 30, 300) - 300) < 1e-9


@settings(max_examples=60, deadline=None)
@given(iters=st.integers(10, 5000), final_at=st.floats(0.05, 0.95),
       s_final=st.floats(400.0, 1e5), ramp=st.floats(0.05, 1.0))
def test_the_finishing_phase_keeps_the_ramp_then_rises_monotonically_to_s_final(
        iters, final_at, s_final, ramp):
    from voxnero.config import resolve
    from voxnero.shape import schedules
    from voxnero.shape.config import ShapeConfig

    cfg = resolve(ShapeConfig, "shape", "standard",
                  [f"iters={iters}", f"neus.final_at={final_at}", f"neus.s_final={s_final}",
                   f"neus.ramp={ramp}"])
    plain = resolve(ShapeConfig, "shape", "standard",
                    [f"iters={iters}", "neus.s_final=1", f"neus.ramp={ramp}"])
    s = [schedules.sharpness(cfg, k) for k in range(iters + 1)]
    assert all(math.isfinite(v) and v > 0 for v in s)
    assert all(b >= a * (1 - 1e-12) for a, b in zip(s[:-1], s[1:], strict=True))  # never falls
    assert math.isclose(s[-1], max(s_final, schedules.sharpness(plain, iters)), rel_tol=1e-9)
    start = int(final_at * iters)
    for k in range(0, start + 1, max(start // 7, 1)):  # before the phase: the old schedule
        assert s[k] == schedules.sharpness(plain, k)
    assert schedules.coarse_samples(cfg, 0) == cfg.sampling.coarse
    assert schedules.coarse_samples(cfg, iters) == cfg.sampling.coarse_final


def test_s_final_below_s_end_leaves_the_ramp_and_too_few_final_samples_are_refused():
    from voxnero.config import resolve
    from voxnero.errors import ConfigError
    from voxnero.shape import schedules
    from voxnero.shape.config import ShapeConfig

    low = resolve(ShapeConfig, "shape", "standard", ["neus.s_final=100", "neus.s_end=1e7"])
    ramp = resolve(ShapeConfig, "shape", "standard", ["neus.s_final=1e7", "neus.s_end=1e7"])
    assert all(schedules.sharpness(low, k) == schedules.sharpness(ramp, k)
               for k in range(0, low.iters + 1, 7))
    with pytest.raises(ConfigError, match="coarse_final"):
        resolve(ShapeConfig, "shape", "standard", ["sampling.coarse_final=4"])


def _grazing_sphere(offset: float, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Exact SDF and its slope along the ray ``(t, 1 + offset, 0)`` past the unit sphere."""
    pts = torch.stack([z, torch.full_like(z, 1.0 + offset), torch.zeros_like(z)], -1)
    r = pts.norm(dim=-1)
    return r - 1.0, pts[..., 0] / r


@settings(max_examples=40, deadline=None)
@given(st.floats(-0.02, 0.02), st.floats(0.0, 1.0), st.sampled_from([0.01, 0.03, 0.06]),
       st.sampled_from([400.0, 1600.0]))
def test_a_dip_between_two_samples_gets_the_opacity_of_dense_samples(offset, phase, h, s):
    """A ray that grazes a convex surface reaches its SDF minimum between two samples; the
    sequence opacity of the samples alone misses the dip (a thin rod or a rounded edge then
    renders too transparent at its outline), the dip-aware opacity matches dense sampling."""
    z = (torch.arange(-6, 7, dtype=torch.float64) + phase - 0.5) * h
    f, g = _grazing_sphere(offset, z)
    dense = torch.linspace(float(z[0]), float(z[-1]), 40001, dtype=torch.float64)
    fd, _ = _grazing_sphere(offset, dense)
    ref = float(composite_weights(alpha_from_sdf_sequence(fd[None], dense[None], s)).sum())
    dip = float(composite_weights(alpha_from_sequence_min(f[None], g[None], z[None], s)).sum())
    assert abs(dip - ref) < 0.03
    assert 0.0 <= dip <= 1.0 + 1e-6  # composite_weights keeps 1e-7 of transmittance


def test_the_dip_opacity_equals_the_sequence_opacity_on_monotone_intervals():
    # a ray head-on into a plane: the SDF falls monotonically, no dip anywhere
    z = torch.linspace(0, 1, 33, dtype=torch.float64)[None]
    sdf = 0.37 - z
    slope = -torch.ones_like(z)
    a = alpha_from_sequence_min(sdf, slope, z, 400.0)
    b = alpha_from_sdf_sequence(sdf, z, 400.0)
    assert torch.equal(a, b)


def test_the_sequence_opacity_misses_a_dip_that_the_dip_opacity_sees():
    # the closest point (0.002 inside the sphere) lies midway between two samples 0.16 apart,
    # both outside it (SDF +0.0012)
    z = torch.tensor([[-0.2, -0.08, 0.08, 0.2]], dtype=torch.float64)
    f, g = _grazing_sphere(-0.002, z[0])
    seq = float(composite_weights(alpha_from_sdf_sequence(f[None], z, 1600.0)).sum())
    dip = float(composite_weights(alpha_from_sequence_min(f[None], g[None], z, 1600.0)).sum())
    assert seq < 0.5 < dip


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-0.05, 0.05), min_size=8, max_size=8),
       st.lists(st.floats(-1.0, 1.0), min_size=8, max_size=8), st.floats(0.001, 0.1),
       st.sampled_from([30.0, 400.0, 1600.0, 1e4]))
def test_the_dip_opacity_has_finite_gradients_everywhere(f, g, h, s):
    """Random values and slopes, equal values, zero slopes and double roots included: the
    opacity and its gradient stay finite (the trainer skips a step with a NaN gradient)."""
    sdf = torch.tensor([f], dtype=torch.float32, requires_grad=True)
    slope = torch.tensor([g], dtype=torch.float32, requires_grad=True)
    z = (torch.arange(8, dtype=torch.float32) * h)[None]
    a = alpha_from_sequence_min(sdf, slope, z, s)
    lo, hi = float(a.min().detach()), float(a.max().detach())
    assert bool(torch.isfinite(a).all()) and lo >= 0.0 and hi <= 1.0
    (a * torch.linspace(0.5, 1.5, 7)).sum().backward()
    assert bool(torch.isfinite(sdf.grad).all()) and bool(torch.isfinite(slope.grad).all())


def test_the_dip_opacity_gradient_is_finite_when_the_quadratic_degenerates():
    # equal values and opposite unit slopes: the Hermite derivative's leading coefficient is 0,
    # so the root comes from the linear fallback
    sdf = torch.tensor([[0.0, 0.0]], requires_grad=True)
    slope = torch.tensor([[-1.0, 1.0]], requires_grad=True)
    z = torch.tensor([[0.0, 1.0]])
    alpha_from_sequence_min(sdf, slope, z, 10.0).sum().backward()
    assert bool(torch.isfinite(sdf.grad).all()) and bool(torch.isfinite(slope.grad).all())
