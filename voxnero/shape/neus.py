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
