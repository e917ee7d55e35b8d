"""sRGB <-> linear conversion and a simple tone map; the only place with sRGB maths.

Every function accepts a numpy array or a torch tensor (any shape) and returns the same kind,
dtype and device. Linear values are radiance-like (scene-referred); sRGB values are the encoded
values stored in 8/16-bit images, in [0, 1].

The curve is the exact piecewise IEC 61966-2-1 sRGB transfer function:

* encode (``linear_to_srgb``): ``12.92 L`` for ``L <= 0.0031308``, else
  ``1.055 L^(1/2.4) - 0.055``;
* decode (``srgb_to_linear``): ``V / 12.92`` for ``V <= 0.04045``, else
  ``((V + 0.055) / 1.055)^2.4``.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np
import torch

Array = TypeVar("Array", np.ndarray, torch.Tensor)

LINEAR_KNEE = 0.0031308
"""Linear value where the sRGB encoding switches from the linear segment to the power law."""
SRGB_KNEE = 0.04045
"""Encoded value where the sRGB decoding switches from the linear segment to the power law."""


def _is_torch(x) -> bool:
    return isinstance(x, torch.Tensor)


def _as_float(x):
    if _is_torch(x):
        return x if x.is_floating_point() else x.float()
    x = np.asarray(x)
    return x if np.issubdtype(x.dtype, np.floating) else x.astype(np.float32)


def srgb_to_linear(x: Array) -> Array:
    """Decode sRGB-encoded values to linear.

    Args:
        x: encoded values, any shape, nominally in [0, 1] (values outside are extended with the
            same formulas, negative values mirrored: the linear segment applies below the knee).

    Returns:
        Linear values, same shape/type (float).
    """
    x = _as_float(x)
    if _is_torch(x):
        low = x / 12.92
        high = ((x.clamp_min(SRGB_KNEE) + 0.055) / 1.055) ** 2.4
        return torch.where(x <= SRGB_KNEE, low, high)
    low = x / 12.92
    high = ((np.maximum(x, SRGB_KNEE) + 0.055) / 1.055) ** 2.4
    return np.where(x <= SRGB_KNEE, low, high).astype(x.dtype, copy=False)


def linear_to_srgb(x: Array) -> Array:
    """Encode linear values to sRGB; the input is clipped to [0, 1] first.

    Args:
        x: linear values, any shape.

    Returns:
        Encoded values in [0, 1], same shape/type (float).
    """
    x = _as_float(x)
    if _is_torch(x):
        x = x.clamp(0.0, 1.0)
        low = 12.92 * x
        high = 1.055 * x.clamp_min(LINEAR_KNEE) ** (1.0 / 2.4) - 0.055
        return torch.where(x <= LINEAR_KNEE, low, high)
    x = np.clip(x, 0.0, 1.0)
    low = 12.92 * x
    high = 1.055 * np.maximum(x, LINEAR_KNEE) ** (1.0 / 2.4) - 0.055
    return np.where(x <= LINEAR_KNEE, low, high).astype(x.dtype, copy=False)


def srgb_slope(x: Array) -> Array:
    """Derivative d linear_to_srgb / dL of the encoding at linear values x in [0, 1].

    ``12.92`` on the linear segment (``L <= 0.0031308``), else ``(1.055 / 2.4) L^(1/2.4 - 1)``
    (12.7 at the knee, 0.44 at 1); values above 1 get the slope at 1 (the encoding clips there).

    Args:
        x: linear values, any shape.

    Returns:
        Slopes, same shape/type (float), in [0.43, 12.92].
    """
    x = _as_float(x)
    if _is_torch(x):
        x = x.clamp(0.0, 1.0)
        high = (1.055 / 2.4) * x.clamp_min(LINEAR_KNEE) ** (1.0 / 2.4 - 1.0)
        return torch.where(x <= LINEAR_KNEE, torch.full_like(x, 12.92), high)
    x = np.clip(x, 0.0, 1.0)
    high = (1.055 / 2.4) * np.maximum(x, LINEAR_KNEE) ** (1.0 / 2.4 - 1.0)
    return np.where(x <= LINEAR_KNEE, 12.92, high).astype(x.dtype, copy=False)


def tonemap(x: Array, exposure: float = 1.0) -> Array:
    """Tone map linear HDR radiance to sRGB-encoded [0, 1] values for PNG previews.

    The operator is Reinhard's global curve applied per channel after an exposure scale,
    ``y = e x / (1 + e x)`` (``e = exposure``, negatives clamped to 0), then the sRGB encoding.
    It is monotonic, maps 0 to 0 and never clips (``y < 1`` for finite input); a value of 1
    maps to 0.5 before encoding. Use it only for previews, never for data.

    Args:
        x: linear radiance, any shape (usually ``(H, W, 3)``).
        exposure: multiplier applied before the curve.

    Returns:
        sRGB-encoded values in [0, 1), same shape/type.
    """
    x = _as_float(x)
    if _is_torch(x):
        s = (x * exposure).clamp_min(0.0)
    else:
        s = np.maximum(x * exposure, 0.0)
    return linear_to_srgb(s / (1.0 + s))
