"""A coarse, reliability-gated second step of the SDF grid (``grid.coarse_step``).

Adam moves every voxel of the dense SDF grid by about the learning rate, whatever its gradient,
and only where rays put gradient. A flat face of one colour shows its depth only at its
outline, so a fat face's edges retreat while its middle, which no pixel pulls, stays out: the
grid sits in a state where moving the face *and* sharpening its edges together would fit the
photos better, but neither alone does (docs/STAGE1.md, findings 31-32).

This step adds, after the grid's own Adam step, a step of a coarse copy of the grid: the SDF
gradient averaged over blocks of ``k³`` voxels, its own Adam moments, the step upsampled
trilinearly onto the grid. A block that an outline pulls moves as a whole, so the face follows
its edges. Each block's step is scaled by its gradient's reliability ``m̂² / v̂`` (1 for a
gradient that keeps its sign, about 0.05 for noise at β₁ = 0.9): blocks whose averaged gradient
is noise barely move, which keeps a mirror's normals (ungated, the knot lost 0.09 px).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F


class CoarseStep:
    """Adam moments of the block-averaged SDF gradient and the gated, upsampled step.

    Args:
        factor: block side ``k`` in voxels (the coarse grid has ``round(res / k)`` samples per
            axis, at least 2).
        betas: Adam's moment decays; the trainer passes its SDF group's.
        eps: Adam's denominator floor; the trainer passes its SDF group's.
    """

    def __init__(self, factor: int, betas: tuple[float, float] = (0.9, 0.99),
                 eps: float = 1e-15):
        if factor < 1:
            raise ValueError(f"CoarseStep: factor must be >= 1, got {factor}")
        self.factor, self.betas, self.eps = factor, betas, eps
        self.m: torch.Tensor | None = None
        self.v: torch.Tensor | None = None
        self.t = 0

    @torch.no_grad()
    def step(self, grid: torch.Tensor, grad: torch.Tensor, lr: float) -> torch.Tensor:
        """Apply one coarse step to ``grid`` in place and return it.

        Args:
            grid: ``(1, R, R, R)`` SDF grid (unit-frame lengths).
            grad: ``(1, R, R, R)`` the loss's gradient with respect to ``grid`` this step.
            lr: the SDF group's learning rate this step (unit-frame length per step).

        Returns:
            ``(1, R, R, R)`` the upsampled step that was subtracted from ``grid``.
        """
        r = grid.shape[-1]
        rc = max(2, round(r / self.factor))
        g = F.adaptive_avg_pool3d(grad[None], rc)[0]
        if self.m is None or self.m.shape != g.shape:  # first step, or a new resolution
            self.m, self.v, self.t = torch.zeros_like(g), torch.zeros_like(g), 0
        b1, b2 = self.betas
        self.t += 1
        self.m.mul_(b1).add_(g, alpha=1 - b1)
        self.v.mul_(b2).addcmul_(g, g, value=1 - b2)
        mh = self.m / (1 - b1 ** self.t)
        vh = self.v / (1 - b2 ** self.t)
        reliability = (mh * mh / (vh + 1e-30)).clamp(0.0, 1.0)
        upd = lr * reliability * mh / (vh.sqrt() + self.eps)
        up = F.interpolate(upd[None], size=(r, r, r), mode="trilinear", align_corners=True)[0]
        grid.sub_(up)
        return up
