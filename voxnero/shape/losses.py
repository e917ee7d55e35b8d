"""Stage-1 losses (pure functions): colour, eikonal, grid smoothness, occlusion."""

from __future__ import annotations

import torch
import torch.nn.functional as F

from voxnero.io.color import linear_to_srgb


def camera_response(pred: torch.Tensor, target: torch.Tensor, sat: float = 0.999
                    ) -> torch.Tensor:
    """Apply the camera's clipping only where the photo is saturated.

    An 8-bit photo clips radiance at 1; a prediction above 1 where the target is saturated is
    not an error. Clipping *everywhere* would kill the gradient of too-bright predictions of
    unsaturated pixels, so clip only where ``target ≥ sat``.

    Args:
        pred: ``(N, 3)`` linear prediction; target: ``(N, 3)`` linear target in [0, 1].

    Returns:
        ``(N, 3)`` prediction, ``min(pred, 1)`` on saturated target channels, floored at 0.
    """
    clipped = torch.where(target >= sat, pred.clamp(max=1.0), pred)
    return clipped.clamp(min=0.0)


_SRGB_SLOPE_AT_1 = 1.055 / 2.4
"""d sRGB / d linear at linear = 1."""


def encode_unclipped(x: torch.Tensor) -> torch.Tensor:
    """sRGB encoding of ``x ≥ 0`` continued linearly above 1 (same slope as at 1).

    :func:`voxnero.io.color.linear_to_srgb` clips at 1, which would give a too-bright prediction
    of an unsaturated pixel no gradient; the continuation keeps one.
    """
    return linear_to_srgb(x.clamp(max=1.0)) + _SRGB_SLOPE_AT_1 * torch.relu(x - 1.0)


def charbonnier(pred: torch.Tensor, target: torch.Tensor, eps: float = 1e-3) -> torch.Tensor:
    """Mean Charbonnier penalty ``sqrt((pred − target)² + eps²) − eps`` (a smooth L1)."""
    return (torch.sqrt((pred - target) ** 2 + eps * eps) - eps).mean()


def compared(pred: torch.Tensor, target: torch.Tensor, space: str = "srgb"
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Linear ``pred`` and ``target (N, 3)`` as the colour terms compare them: the camera's
    clipping applied (:func:`camera_response`), then sRGB-encoded (perceptually even, as the
    photos were stored; ``pred`` continued above 1) or left linear."""
    p = camera_response(pred, target)
    if space == "srgb":
        return encode_unclipped(p), linear_to_srgb(target)
    return p, target


def color_loss(pred: torch.Tensor, target: torch.Tensor, eps: float = 1e-3,
               space: str = "srgb") -> torch.Tensor:
    """Charbonnier colour loss between linear ``pred (N, 3)`` and linear ``target (N, 3)``,
    compared in sRGB or linear space (:func:`compared`)."""
    return charbonnier(*compared(pred, target, space), eps)


@torch.no_grad()
def pixel_error(pred: torch.Tensor, target: torch.Tensor, space: str = "srgb") -> torch.Tensor:
    """``(N,)`` mean absolute colour error per pixel of linear ``pred`` and ``target (N, 3)``,
    in the space :func:`color_loss` compares them (no gradient: it steers the sampling)."""
    p, t = compared(pred, target, space)
    return (p - t).abs().mean(-1)


def eikonal(grad: torch.Tensor) -> torch.Tensor:
    """Mean ``(|∇f| − 1)²`` over gradients ``(M, 3)``."""
    if grad.numel() == 0:
        return grad.sum()
    return ((grad.norm(dim=-1) - 1.0) ** 2).mean()


def laplacian(grid: torch.Tensor, voxel: float) -> torch.Tensor:
    """Mean squared discrete Laplacian of a ``(D, H, W)`` grid, interior voxels.

    Values are divided by ``voxel`` first, so an exact SDF of a plane scores 0 and a sphere of
    radius ρ scores ≈ (2·voxel/ρ)² (the Laplacian of |x| − ρ is 2/|x|).
    """
    g = grid / voxel
    lap = (g[2:, 1:-1, 1:-1] + g[:-2, 1:-1, 1:-1] + g[1:-1, 2:, 1:-1] + g[1:-1, :-2, 1:-1]
           + g[1:-1, 1:-1, 2:] + g[1:-1, 1:-1, :-2] - 6.0 * g[1:-1, 1:-1, 1:-1])
    return (lap * lap).mean()


def normal_smoothness(n_a: torch.Tensor, n_b: torch.Tensor) -> torch.Tensor:
    """Mean squared difference of unit normals at nearby surface points ``(N, 3)`` each.

    With ``n_b`` taken a fraction of a voxel away from ``n_a`` this penalises the voxel-scale
    bumps that a dense grid grows (NeRO/Neuralangelo-style smoothness); 0 for a plane.
    """
    if n_a.numel() == 0:
        return n_a.sum()
    return ((n_a - n_b) ** 2).sum(-1).mean()


def occlusion_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean L1 between predicted occlusion ``(N, 1)`` and ray-cast targets ``(N, 1)`` in {0, 1}."""
    if pred.numel() == 0:
        return pred.sum()
    return F.l1_loss(pred, target)


def psnr(pred: torch.Tensor, target: torch.Tensor) -> float:
    """PSNR (dB) of sRGB-encoded, clipped colours — what a viewer sees."""
    from voxnero.eval.images import psnr as image_psnr

    p = linear_to_srgb(pred.detach().clamp(0, 1))
    t = linear_to_srgb(target.detach().clamp(0, 1))
    return min(image_psnr(p, t), 120.0)  # identical colours: capped for the progress bar
