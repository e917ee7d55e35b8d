"""Ref-NeRF's integrated directional encoding (IDE) of a reflected direction, from the complex
spherical harmonics of ``sh.py`` attenuated by a von Mises-Fisher lobe of the roughness."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor

from voxnero.render.sh import complex_sh

IDE_LEVELS: tuple[int, ...] = (1, 2, 4, 8, 16)


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
    comp = complex_sh(d, list(levels))
    alpha = roughness.clamp(0.0, 1.0) ** 2
    re, im = [], []
    for l in levels:
        att = torch.exp(-0.5 * l * (l + 1) * alpha)
        for m in range(l + 1):
            r_, i_ = comp[(l, m)]
            re.append(r_[..., None] * att)
            im.append(i_[..., None] * att)
    return torch.cat(re + im, dim=-1)
