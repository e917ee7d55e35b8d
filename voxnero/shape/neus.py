"""NeuS: signed distance → per-sample opacity → compositing weights (pure functions).

Samples along each ray stand for intervals ``[t − δ/2, t + δ/2]``. With the logistic CDF
``Φ_s(f) = sigmoid(s·f)`` of sharpness ``s`` (1/length units; the kernel's width is ≈ 1/s),
the discrete opacity of an interval whose SDF goes from ``f_prev`` to ``f_next`` is
``α = clamp((Φ_s(f_prev) − Φ_s(f_next)) / Φ_s(f_prev), 0, 1)`` (Wang et al. 2021, eq. 13). It is
unbiased: for a plane crossed head-on the weights peak at the zero crossing.

The sharpness is *scheduled*, not learned: a learned ``s`` collapsed in the DESIGN probe
(20 → 8 in ~100 steps), after which a too-large shape had the lower colour loss.
"""

from __future__ import annotations

import math

import torch


def alpha_from_interval(f_prev: torch.Tensor, f_next: torch.Tensor, s: float | torch.Tensor
                        ) -> torch.Tensor:
    """NeuS opacity of intervals whose SDF goes from ``f_prev`` to ``f_next``.

    Args:
        f_prev, f_next: ``(...)`` SDF at the interval's start and end (negative inside).
        s: sharpness (> 0), scalar.

    Returns:
        ``(...)`` opacity in [0, 1].
    """
    # (Φ(a) − Φ(b)) / Φ(a) = 1 − Φ(b)/Φ(a) = 1 − exp(logσ(sb) − logσ(sa)); log-space is stable.
    la = torch.nn.functional.logsigmoid(s * f_prev)
    lb = torch.nn.functional.logsigmoid(s * f_next)
    # a ray leaving the surface has lb > la and α = 0; capping the exponent at 0 keeps that value
    # and avoids exp → inf there, whose backward (0 · inf) made the SDF gradient NaN for
    # s·Δf > 88 (float32), e.g. s = 1e3 across a 0.1 step (tests/stability/)
    return (1.0 - torch.exp((lb - la).clamp(max=0.0))).clamp(0.0, 1.0)


def alpha_from_samples(sdf: torch.Tensor, cos: torch.Tensor, dists: torch.Tensor,
                       s: float | torch.Tensor) -> torch.Tensor:
    """NeuS opacity of samples from their SDF and directional derivative (section midpoints).

    The SDF at the interval ends is extrapolated linearly, ``f ∓ cos·δ/2``, with
    ``cos = −relu(−∇f·d)`` so that only a ray entering the surface gains opacity (NeuS, fully
    annealed).

    Args:
        sdf: ``(R, S)`` SDF at the samples.
        cos: ``(R, S)`` ``∇f · d`` (ray direction d unit, ∇f the SDF gradient).
        dists: ``(R, S)`` interval lengths δ.
        s: sharpness.

    Returns:
        ``(R, S)`` opacity.
    """
    c = -torch.relu(-cos)
    half = c * dists * 0.5
    return alpha_from_interval(sdf - half, sdf + half, s)


def alpha_from_sdf_sequence(sdf: torch.Tensor, z: torch.Tensor, s: float | torch.Tensor
                            ) -> torch.Tensor:
    """Opacity of the ``S − 1`` intervals between consecutive samples (no gradient needed).

    Used by the coarse pass of the sampler. Args: ``sdf (R, S)``, ``z (R, S)`` sorted depths.
    Returns ``(R, S − 1)``.
    """
    return alpha_from_interval(sdf[:, :-1], sdf[:, 1:], s)


def alpha_from_sequence_min(sdf: torch.Tensor, slope: torch.Tensor, z: torch.Tensor,
                            s: float | torch.Tensor) -> torch.Tensor:
    """Opacity of the ``S − 1`` intervals between consecutive samples, counting the SDF's dip
    between two samples.

    A ray that grazes a convex surface (a thin rod, a rounded edge at the outline) reaches its
    smallest SDF between two samples; :func:`alpha_from_sdf_sequence` sees only the two
    samples' values and renders such a ray too transparent (a dip 0.002 inside a sphere
    midway between samples 0.16 apart, s = 1600: 0.13 instead of 0.96), so the outline of a
    thin part renders thinner than the shape and the fit widens the shape. Where the slope
    along the ray goes from negative to positive inside an interval, its minimum is taken from
    the cubic Hermite interpolant of the two values and slopes (clamped between the 1-Lipschitz
    bound ``(f0 + f1 − h)/2`` and the smaller value), and the interval's opacity is that of the
    approach to it, ``alpha_from_interval(f0, min)`` (the way out adds none, as in NeuS).
    Monotone intervals get exactly :func:`alpha_from_sdf_sequence`'s opacity.

    Args:
        sdf: ``(R, S)`` SDF at the samples.
        slope: ``(R, S)`` the SDF's derivative along the ray, ``∇f · d`` (d unit).
        z: ``(R, S)`` sorted sample depths (same length unit as the SDF).
        s: sharpness.

    Returns:
        ``(R, S − 1)`` opacity in [0, 1].
    """
    f0, f1, g0, g1 = sdf[:, :-1], sdf[:, 1:], slope[:, :-1], slope[:, 1:]
    h = (z[:, 1:] - z[:, :-1]).clamp(min=1e-9)
    dip = (g0 < 0) & (g1 > 0)
    a0, a1 = h * g0, h * g1  # the slopes per unit of u = (t − t0) / h
    with torch.no_grad():
        # where the Hermite cubic p(u) is smallest: p'(u) = A u^2 + B u + C has one root in
        # (0, 1) on a dip. At a minimum p'(u) = 0, so the value's gradient needs no gradient
        # of u (envelope theorem): the root is found without autograd, whose sqrt and
        # divisions at near-double roots gave NaN gradients in training.
        qa = 6 * f0 + 3 * a0 - 6 * f1 + 3 * a1
        qb = -6 * f0 - 4 * a0 + 6 * f1 - 2 * a1
        qc = a0
        root = torch.sqrt((qb * qb - 4 * qa * qc).clamp(min=0.0))
        q = -0.5 * (qb + torch.where(qb >= 0, root, -root))  # stable roots q/A and C/q
        r1 = q / torch.where(qa.abs() > 1e-12, qa, torch.ones_like(qa))
        r2 = qc / torch.where(q.abs() > 1e-30, q, torch.ones_like(q))
        u = torch.where((qa.abs() > 1e-12) & (r1 > 0) & (r1 < 1), r1, r2).clamp(0.0, 1.0)
    m = ((2 * u ** 3 - 3 * u ** 2 + 1) * f0 + (u ** 3 - 2 * u ** 2 + u) * a0
         + (-2 * u ** 3 + 3 * u ** 2) * f1 + (u ** 3 - u ** 2) * a1)
    m = torch.maximum(torch.minimum(m, torch.minimum(f0, f1)), 0.5 * (f0 + f1 - h))
    return alpha_from_interval(f0, torch.where(dip, m, f1), s)


def composite_weights(alpha: torch.Tensor) -> torch.Tensor:
    """Front-to-back compositing weights ``w_i = α_i Π_{j<i} (1 − α_j)``.

    Args:
        alpha: ``(R, S)``.

    Returns:
        ``(R, S)`` weights; their sum along S is the ray's accumulated opacity (≤ 1).
    """
    trans = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha + 1e-7], 1), 1)
    return alpha * trans[:, :-1]


def sharpness_schedule(frac: float, s_start: float, s_end: float) -> float:
    """Geometric ramp of the NeuS sharpness: ``s_start`` at ``frac = 0`` → ``s_end`` at 1."""
    f = min(max(frac, 0.0), 1.0)
    return math.exp(math.log(s_start) + f * (math.log(s_end) - math.log(s_start)))
