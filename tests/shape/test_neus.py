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
