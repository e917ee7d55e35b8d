"""Spherical harmonics: the one real SH basis, the projection of an env map and the irradiance
from its order-2 coefficients (Ramamoorthi and Hanrahan 2001).

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

from voxnero.render.latlong import pixel_dirs, pixel_solid_angles
from voxnero.render.microfacet import safe_normalize


def _norm(l: int, m: int) -> float:
    return math.sqrt((2 * l + 1) / (4 * math.pi) * math.exp(math.lgamma(l - m + 1)
                                                             - math.lgamma(l + m + 1)))


def complex_sh(d: Tensor, degrees: Sequence[int]) -> dict[tuple[int, int], tuple[Tensor, Tensor]]:
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
    comp = complex_sh(d, list(range(degree + 1)))
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


_SH_BAND_GAIN = (math.pi, 2.0 * math.pi / 3.0, math.pi / 4.0)


def sh9_project(img: Tensor) -> Tensor:
    """Project a map onto the 9 real SH of bands 0-2 (pixel-cell quadrature).

    Args:
        img: (H, W, C) linear radiance.

    Returns:
        (9, C) coefficients c_lm = sum L(d) y_lm(d) dOmega (``sh_basis`` ordering).
    """
    H, W = img.shape[:2]
    Y = sh_basis(pixel_dirs(H, W, device=img.device, dtype=img.dtype), 2)  # (H, W, 9)
    om = pixel_solid_angles(H, W, device=img.device, dtype=img.dtype)
    return torch.einsum("hwk,hw,hwc->kc", Y, om, img)


def sh9_irradiance(coeffs: Tensor, n: Tensor) -> Tensor:
    """Irradiance E(n) = integral L(l) max(n.l, 0) dl from order-2 SH (Ramamoorthi-Hanrahan).

    Clamped at 0 (order-2 SH of a very peaked light can ring negative). Diffuse outgoing
    radiance is albedo / pi * E.

    Args:
        coeffs: (9, C) from ``sh9_project``.
        n: (..., 3) unit normals.

    Returns:
        (..., C) irradiance (W m^-2 sr^0 in radiance units times sr).
    """
    Y = sh_basis(n.to(coeffs.dtype), 2)
    gain = torch.tensor([_SH_BAND_GAIN[0]] + [_SH_BAND_GAIN[1]] * 3 + [_SH_BAND_GAIN[2]] * 5,
                        dtype=coeffs.dtype, device=coeffs.device)
    return ((Y * gain) @ coeffs).clamp_min(0.0)
