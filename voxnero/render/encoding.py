"""Directional encodings: real spherical harmonics and Ref-NeRF's integrated directional encoding.

Spherical harmonics are evaluated as polynomials in the unit direction (x, y, z), with no
trigonometry and no Condon-Shortley phase:

    Y_l^m(d) = K_lm Q_l^m(z) (x + i y)^m,   K_lm = sqrt((2l + 1) (l - m)! / (4 pi (l + m)!)),

where Q_l^m = P_l^m / (1 - z^2)^(m/2) is a polynomial (upward recurrence in l). Real SH:
y_l0 = Y_l^0, y_l,+m = sqrt(2) Re Y_l^m, y_l,-m = sqrt(2) Im Y_l^m, index l^2 + l + m. They are
orthonormal over the sphere and finite, with finite gradients, everywhere (poles included).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from voxnero.render.brdf import safe_normalize

IDE_LEVELS: tuple[int, ...] = (1, 2, 4, 8, 16)


def _norm(l: int, m: int) -> float:
    return math.sqrt((2 * l + 1) / (4 * math.pi) * math.exp(math.lgamma(l - m + 1)
                                                             - math.lgamma(l + m + 1)))


def _complex_sh(d: Tensor, degrees: Sequence[int]) -> dict[tuple[int, int], tuple[Tensor, Tensor]]:
    """Re and Im of the complex Y_l^m (m = 0..l) for the requested degrees l."""
    d = safe_normalize(d)
    x, y, z = d.unbind(-1)
    L = max(degrees)
    want = set(degrees)
    # powers (x + i y)^m
    cs = [(torch.ones_like(x), torch.zeros_like(x))]
    for _ in range(L):
        c, s = cs[-1]
        cs.append((c * x - s * y, s * x + c * y))
    out: dict[tuple[int, int], tuple[Tensor, Tensor]] = {}
    qmm = torch.ones_like(z)
    for m in range(L + 1):
        if m > 0:
            qmm = qmm * (2 * m - 1)
        q_prev2, q_prev = None, qmm  # Q_{l-2}^m, Q_{l-1}^m, starting at l = m
        for l in range(m, L + 1):
            if l == m:
                q = qmm
            elif l == m + 1:
                q = z * (2 * m + 1) * qmm
            else:
                q = ((2 * l - 1) * z * q_prev - (l + m - 1) * q_prev2) / (l - m)
            if l > m:
                q_prev2, q_prev = q_prev, q
            if l in want:
                k = _norm(l, m) * q
                out[(l, m)] = (k * cs[m][0], k * cs[m][1])
    return out


def sh_basis(d: Tensor, degree: int) -> Tensor:
    """Real orthonormal spherical harmonics up to ``degree``.

    Args:
        d: (..., 3) directions (normalised internally).
        degree: largest band l (>= 0).

    Returns:
        (..., (degree + 1)^2) values, index l^2 + l + m for m in [-l, l].
    """
    comp = _complex_sh(d, list(range(degree + 1)))
    cols = []
    for l in range(degree + 1):
        for m in range(-l, l + 1):
            re, im = comp[(l, abs(m))]
            if m == 0:
                cols.append(re)
            elif m > 0:
                cols.append(math.sqrt(2.0) * re)
            else:
                cols.append(math.sqrt(2.0) * im)
    return torch.stack(cols, dim=-1)


def ide(d: Tensor, roughness: Tensor, levels: Sequence[int] = IDE_LEVELS) -> Tensor:
    """Ref-NeRF integrated directional encoding of a reflected direction.

    IDE = [Re Y_l^m(d) A_l, Im Y_l^m(d) A_l] for l in ``levels`` and m = 0..l (all real parts
    first, then all imaginary parts; m = 0 imaginary parts are identically 0, kept for Ref-NeRF's
    layout), with the von Mises-Fisher attenuation A_l = exp(-l (l + 1) / (2 kappa)).
    Convention: kappa = 1 / alpha with alpha = clamp(roughness, 0, 1)^2 (no ALPHA_MIN floor),
    so A_l = exp(-l (l + 1) alpha / 2) and roughness 0 gives the plain SH values.

    Args:
        d: (..., 3) unit reflected directions.
        roughness: (..., 1) perceptual roughness.
        levels: SH degrees l (default (1, 2, 4, 8, 16): 72 features).

    Returns:
        (..., 2 * sum(l + 1)) encoding, (..., 72) for the default levels.
    """
    comp = _complex_sh(d, list(levels))
    alpha = roughness.clamp(0.0, 1.0) ** 2
    re, im = [], []
    for l in levels:
        att = torch.exp(-0.5 * l * (l + 1) * alpha)
        for m in range(l + 1):
            r_, i_ = comp[(l, m)]
            re.append(r_[..., None] * att)
            im.append(i_[..., None] * att)
    return torch.cat(re + im, dim=-1)
