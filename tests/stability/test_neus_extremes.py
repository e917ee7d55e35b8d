"""NeuS at extreme sharpness (voxnero/shape/neus.py and the stage-1 renderer), float32.

Checked against: the definition (opacity in [0, 1], compositing weights summing to at most 1,
up to the documented ``+1e-7`` per sample of ``composite_weights``), the closed form of a plane
crossed head-on (all opacity in the interval that contains the crossing) and exact IEEE
finiteness of values and of gradients with respect to the SDF. Sharpness 1e3, 1e5, 1e7 and the
scheduled maximum (``ShapeConfig().neus.s_end``).
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
    tiny_model,
    tiny_shape_config,
)
from voxnero.shape.neus import (
    alpha_from_interval,
    alpha_from_samples,
    alpha_from_sdf_sequence,
    composite_weights,
)
from voxnero.shape.renderer import render_rays

SHARPNESS = [1e3, 1e5, 1e7, S_SCHEDULED_MAX]
CUMPROD_EPS = 1e-7
"""``composite_weights`` multiplies transmittance by ``1 − α + 1e-7`` (finite cumprod backward),
so a ray's weights may exceed 1 by at most ``S · 1e-7`` for S samples."""


def _check_weights(alpha: torch.Tensor, w: torch.Tensor) -> None:
    assert torch.isfinite(alpha).all() and torch.isfinite(w).all()
    assert (alpha >= 0).all() and (alpha <= 1).all()
    assert (w >= 0).all()
    assert (w.sum(-1) <= 1.0 + CUMPROD_EPS * w.shape[-1] + 1e-6).all(), w.sum(-1).max()


sdf_value = st.one_of(st.just(0.0), st.just(-0.0), st.floats(-2.0, 2.0),
                      st.floats(-1e-6, 1e-6))


@settings(max_examples=150, deadline=None)
@given(st.floats(0.0, 7.0), st.lists(sdf_value, min_size=2, max_size=24),
       st.lists(st.integers(0, 22), max_size=4))
def test_sequence_opacity_weights_and_sdf_gradients_finite(log_s, values, repeat):
    """Any SDF sequence (zeros, signed zeros, equal neighbours, sign changes) and any
    s in [1, 1e7]: α in [0, 1], Σw ≤ 1 (+S·1e-7), finite values and d/d sdf."""
    s = 10.0 ** log_s
    for i in repeat:  # equal consecutive values
        if i + 1 < len(values):
            values[i + 1] = values[i]
    f = torch.tensor([values], dtype=torch.float32, requires_grad=True)
    z = torch.linspace(0, 1, len(values))[None]
    a = alpha_from_sdf_sequence(f, z, s)
    w = composite_weights(a)
    _check_weights(a, w)
    (w * torch.linspace(1, 2, w.shape[-1])).sum().backward()
    assert torch.isfinite(f.grad).all(), (s, values, f.grad)


@settings(max_examples=100, deadline=None)
@given(st.floats(0.0, 7.0), st.lists(sdf_value, min_size=1, max_size=16),
       st.lists(st.one_of(st.just(0.0), st.floats(-1.0, 1.0)), min_size=1,
                max_size=16))
def test_section_opacity_and_gradients_finite(log_s, values, cosines):
    """The per-sample ("section") opacity with cos = ∇f·d in [−1, 1] (including 0)."""
    s = 10.0 ** log_s
    k = min(len(values), len(cosines))
    f = torch.tensor([values[:k]], requires_grad=True)
    c = torch.tensor([cosines[:k]], requires_grad=True)
    a = alpha_from_samples(f, c, torch.full_like(f, 0.05), s)
    w = composite_weights(a)
    _check_weights(a, w)
    w.sum().backward()
    assert torch.isfinite(f.grad).all() and torch.isfinite(c.grad).all()


@pytest.mark.parametrize("s", SHARPNESS)
def test_leaving_the_surface_gives_no_opacity_and_finite_gradient(s):
    """Exit intervals with s·Δf far beyond float32's exp range (e.g. 1e3 · 2): α = 0 exactly,
    gradient 0 and not NaN (the backward of exp → inf used to give 0 · inf = NaN)."""
    f_prev = torch.tensor([-1.0, -0.5, -0.1, 0.0, -2.0], requires_grad=True)
    f_next = torch.tensor([1.0, 0.5, 0.0, 0.1, 2.0], requires_grad=True)
    a = alpha_from_interval(f_prev, f_next, s)
    assert torch.equal(a, torch.zeros(5))
    a.sum().backward()
    assert torch.isfinite(f_prev.grad).all() and torch.isfinite(f_next.grad).all()


@pytest.mark.parametrize("s", SHARPNESS)
def test_equal_and_zero_sdf_values(s):
    """f_prev = f_next (inside, outside, exactly 0): the CDF does not change, α = 0 exactly;
    a whole ray at sdf ≡ 0 gets no weight; gradients finite."""
    f = torch.tensor([[-0.3, -0.3, 0.0, 0.0, 0.0, 0.2, 0.2]], requires_grad=True)
    a = alpha_from_interval(f[:, :-1], f[:, 1:], s)
    assert a[0, 0] == 0 and a[0, 2] == 0 and a[0, 3] == 0 and a[0, 5] == 0
    a.sum().backward()
    assert torch.isfinite(f.grad).all()
    flat = torch.zeros(1, 9, requires_grad=True)
    w = composite_weights(alpha_from_sdf_sequence(flat, torch.linspace(0, 1, 9)[None], s))
    assert float(w.detach().sum()) == 0.0
    w.sum().backward()
    assert torch.isfinite(flat.grad).all()


@pytest.mark.parametrize("s", SHARPNESS)
@pytest.mark.parametrize("t0", [0.3, 0.5, 0.51234])
def test_plane_crossing_weight_peaks_at_the_crossing(s, t0):
    """Ray along +t through the plane sdf = t0 − t (entering), 101 samples on [0, 1]:
    the largest weight is the interval that contains t0 (for t0 on a sample, sdf exactly 0
    there, one of the two intervals that touch it) and the weights sum to 1 − O(1e-5)."""
    z = torch.linspace(0, 1, 101)[None]
    f = (t0 - z).requires_grad_(True)
    a = alpha_from_sdf_sequence(f, z, s)
    w = composite_weights(a)
    _check_weights(a, w)
    i = int(w.argmax())
    assert float(z[0, i]) - 1e-6 <= t0 <= float(z[0, i + 1]) + 1e-6, (i, float(z[0, i]))
    assert float(w.detach().sum()) > 1.0 - 1e-4
    (w * torch.arange(100.0)).sum().backward()
    assert torch.isfinite(f.grad).all()
    # the per-sample ("section") opacity with the exact derivative cos = −1: peak at the sample
    # nearest the crossing
    ws = composite_weights(alpha_from_samples(t0 - z, -torch.ones_like(z),
                                              torch.full_like(z, 0.01), s))
    assert abs(float(z[0, ws.argmax()]) - t0) <= 0.005 + 1e-6


@pytest.mark.parametrize("alpha_mode", ["sequence", "section"])
@pytest.mark.parametrize("s", SHARPNESS)
def test_renderer_at_extreme_sharpness(s, alpha_mode):
    """The stage-1 renderer on the initial sphere SDF (r = 0.7): finite colour, accumulated
    opacity in [0, 1] (+S·1e-7), ≈ 1 for rays through the middle of the sphere and 0 for rays
    that miss it; finite gradients of every parameter (SDF grid, features, heads, env)."""
    cfg = tiny_shape_config(neus={"alpha": alpha_mode})
    m = tiny_model(cfg)
    r0 = cfg.grid.init_radius
    x = torch.linspace(-0.95, 0.95, 24)
    o = torch.stack([x, 0.1 * x, torch.full_like(x, 3.0)], -1)
    d = torch.tensor([0.0, 0.0, -1.0]).expand(24, 3).contiguous()
    m.env.prepare()
    out = render_rays(m, o, d, s, cfg, train=True, generator=torch.Generator().manual_seed(0))
    loss = (out["rgb"] ** 2).sum() + 0.1 * ((out["grad"].norm(dim=-1) - 1) ** 2).sum()
    loss.backward()
    m.env.release()
    acc = out["acc"].detach()
    assert torch.isfinite(out["rgb"]).all() and torch.isfinite(acc).all()
    n_samples = cfg.sampling.fine + cfg.sampling.coarse_keep
    assert (acc >= 0).all() and (acc <= 1 + CUMPROD_EPS * n_samples + 1e-6).all()
    rho = (x ** 2 + (0.1 * x) ** 2).sqrt()
    assert (acc[rho < r0 - 0.15] > 0.99).all(), acc
    assert (acc[rho > r0 + 0.15] < 1e-3).all(), acc
    assert assert_finite_grads(m, f"s={s}") >= 4
    assert m.sdf.grid.grad.abs().sum() > 0


@pytest.mark.parametrize("s", [1e3, 1e7])
def test_trainer_steps_at_extreme_sharpness(s, tmp_path):
    """``ShapeTrainer.train_step`` with the schedule pinned at s (s_start = s_end): no step is
    skipped, gradients and parameters stay finite (a NaN gradient would reach Adam and fill the
    grid with NaN — the trainer only guards against a non-finite *loss*)."""
    from tests.fixtures.scenes import make_blender
    from voxnero.config import from_dict
    from voxnero.data.detect import load_scene
    from voxnero.shape.config import ShapeConfig
    from voxnero.shape.trainer import ShapeTrainer

    make_blender(tmp_path / "scene", n={"train": 4}, w=40, h=32, seed=2)
    sc = load_scene(tmp_path / "scene", splits=("train",))
    cfg = from_dict(ShapeConfig, {
        "iters": 50, "eval_every_s": 0, "preview_every": 0,
        "grid": {"res": [24], "upsample_at": []}, "neus": {"s_start": s, "s_end": s},
        "sampling": {"rays": 512, "coarse": 24, "fine": 8, "coarse_keep": 12},
        "light": {"env_height": 8}})
    msgs: list[str] = []
    tr = ShapeTrainer(cfg, sc, tmp_path / "run", progress=False, log=msgs.append)
    for i in range(4):
        rec = tr.train_step()
        tr.step += 1
        assert rec["s"] == pytest.approx(s) and math.isfinite(rec["loss"]), (i, msgs)
        assert_finite_grads(tr.model, f"s={s} step {i}")
        assert all(bool(torch.isfinite(p).all()) for p in tr.model.parameters())
