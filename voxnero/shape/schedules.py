"""Stage-1 schedules: pure functions of ``(config, step)``.

Everything the training loop derives from the step number alone: the SDF grid resolution, the
NeuS sharpness, the learning-rate factor, when the regularisers and the occlusion loss switch on
and when an "auto" occlusion is measured. Fractions in the config are fractions of ``iters``
(:mod:`voxnero.shape.config`), so a preset scales with its length; a fraction ``f`` means
"from step ``int(f · iters)`` on".
"""

from __future__ import annotations

import math

from voxnero.shape.config import ShapeConfig
from voxnero.shape.neus import sharpness_schedule


def at(fraction: float, cfg: ShapeConfig) -> int:
    """The step at which a schedule given as a fraction of ``iters`` starts."""
    return int(fraction * cfg.iters)


def grid_res(cfg: ShapeConfig, step: int) -> int:
    """SDF grid resolution at ``step``: ``grid.res[k]`` after the k-th ``grid.upsample_at``."""
    g = cfg.grid
    k = sum(1 for f in g.upsample_at if step >= at(f, cfg))
    return g.res[k]


def sharpness(cfg: ShapeConfig, step: int) -> float:
    """NeuS sharpness s (1/length, unit frame) at ``step``: geometric from ``neus.s_start`` to
    ``neus.s_end`` over ``neus.ramp`` of the run (:func:`voxnero.shape.neus.sharpness_schedule`),
    then, from ``neus.final_at`` of the run, at least the geometric rise from the value there to
    ``neus.s_final`` at the last step (the finishing phase; ``s_final ≤ s_end`` leaves the ramp
    as it is)."""
    n = cfg.neus

    def ramp(k: float) -> float:
        return sharpness_schedule(k / max(cfg.iters * n.ramp, 1), n.s_start, n.s_end)

    start = n.final_at * cfg.iters
    if step <= start:
        return ramp(step)
    rise = sharpness_schedule((step - start) / max(cfg.iters - start, 1e-9), ramp(start),
                              n.s_final)
    return max(ramp(step), rise)


def coarse_samples(cfg: ShapeConfig, step: int) -> int:
    """Coarse samples per ray at ``step``: ``sampling.coarse``, or ``sampling.coarse_final``
    (when set) from ``neus.final_at`` of the run on."""
    sc = cfg.sampling
    if sc.coarse_final > 0 and step >= cfg.neus.final_at * cfg.iters:
        return sc.coarse_final
    return sc.coarse


def lr_factor(cfg: ShapeConfig, step: int) -> float:
    """Factor on every group's base learning rate: linear warm-up over ``optim.warmup`` steps
    times a cosine decay from 1 to ``optim.decay`` over ``iters``."""
    o = cfg.optim
    warm = min(1.0, (step + 1) / max(o.warmup, 1))
    f = min(step / max(cfg.iters, 1), 1.0)
    return warm * (o.decay + (1 - o.decay) * 0.5 * (1 + math.cos(math.pi * f)))


def normal_smooth_on(cfg: ShapeConfig, step: int) -> bool:
    """Whether the normal-smoothness term is on (weight > 0, from ``loss.normal_smooth_start``)."""
    return cfg.loss.normal_smooth > 0 and step >= at(cfg.loss.normal_smooth_start, cfg)


def occlusion_loss_on(cfg: ShapeConfig, step: int) -> bool:
    """Whether the occlusion net is trained on ray-cast targets (from ``loss.occlusion_start``)."""
    return step >= at(cfg.loss.occlusion_start, cfg)


def occlusion_targets_due(cfg: ShapeConfig, step: int) -> bool:
    """Whether the surface for the occlusion targets is rebuilt at ``step`` (every
    ``loss.occlusion_every`` steps; also whenever there are none yet)."""
    return step % cfg.loss.occlusion_every == 0


def occlusion_decision(cfg: ShapeConfig, step: int) -> str:
    """What an undecided "auto" occlusion does at ``step``: ``"wait"`` (before
    ``light.decide_at``, or between two measurements), ``"measure"`` (at ``decide_at`` and then
    every ``loss.occlusion_every`` steps) or ``"close"`` (after ``light.decide_until``: it stays
    as it is)."""
    start = at(cfg.light.decide_at, cfg)
    if step < start:
        return "wait"
    if step > at(cfg.light.decide_until, cfg):
        return "close"
    return "wait" if (step - start) % max(cfg.loss.occlusion_every, 1) else "measure"
