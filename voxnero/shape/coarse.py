"""Stage 1's coarse stage: a free-space density grid that carves fast, as the SDF's start.

The SDF of NeuS only moves where its zero crossing is: voxels far from the current surface get
no gradient, so a sphere that covers a table's legs never opens the gaps between them, and a leg
blurred away early never grows back (docs/STAGE1.md, finding 16). A density field has no such
limit: every sample along a ray gets a gradient through the transmittance. So, as DVGO's and
Voxurf's coarse stages do, a few hundred steps first fit a density grid (the same trilinear
:class:`~voxnero.fields.grid.DenseGrid`) with deferred colour (one feature lookup per ray, at its
expected surface point, as the main stage shades), composited over the scene's background as
the main stage draws it without its near field (:func:`voxnero.shape.renderer.background`:
the learnable env map, which the SDF stage goes on with, or the known colour of images with
alpha; a near field in the coarse stage fitted the hull of dtu_scan97 worse)::

    α_i = 1 − exp(−softplus(raw(x_i) + shift) · δ_i / voxel)       (density per voxel length)
    w_i = α_i ∏_{j<i} (1 − α_j),  acc = Σ w_i
    x̄ = Σ w_i x_i / acc,   pixel = acc · c(x̄, d) + (1 − acc) · background(o, d)

The colour ``c`` is a free MLP of the features at x̄ and the view direction (DVGO's colour). The
main stage's split-sum shading with the density's normal fitted worse in 300 steps (bowl_silver
hull 7.7 against 4.3 px, docs/STAGE1.md finding 17): a density's normal is too rough early.

The grid's occupancy then becomes the SDF's start (:mod:`voxnero.shape.hull`). Unit frame
throughout, linear radiance; the photometric loss is the main stage's
(:func:`voxnero.shape.losses.color_loss`).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn

from voxnero.fields.grid import DenseGrid, trilinear_value_grad
from voxnero.fields.heads import mlp
from voxnero.fields.lights import EnvLight
from voxnero.shape.neus import composite_weights
from voxnero.shape.sampler import ray_sphere, stratified

Background = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
"""``background(origins, dirs)``: linear radiance ``(R, 3)`` behind the object along unit-frame
rays ``(R, 3)`` each (the main stage's :func:`voxnero.shape.renderer.background`)."""


class CoarseModel(nn.Module):
    """Density grid, colour-feature grid and a deferred colour head (the env map is shared).

    Args:
        res: samples per axis of the grid over ``[-bound, bound]³``.
        bound: half-size of the cube (unit frame).
        feat_dim: colour feature channels (a grid of ``feat_res`` samples per axis).
        hidden: width of the colour head.
        alpha_init: opacity of one voxel length of the initial (uniform) density.
    """

    def __init__(self, res: int, bound: float, feat_dim: int = 8, hidden: int = 32,
                 alpha_init: float = 1e-3, feat_res: int = 32):
        super().__init__()
        self.density_grid = DenseGrid(1, res, bound)
        self.feat = DenseGrid(feat_dim, feat_res, bound)
        nn.init.normal_(self.feat.grid, std=0.1)
        self.head = mlp(feat_dim + 3, hidden, 3)
        self.shift = math.log(math.expm1(-math.log1p(-alpha_init)))
        """Softplus shift such that ``raw = 0`` has opacity ``alpha_init`` per voxel length."""

    def density(self, raw: torch.Tensor) -> torch.Tensor:
        """Density in 1/voxel length from raw grid values (any shape)."""
        return F.softplus(raw + self.shift)

    @torch.no_grad()
    def voxel_alpha(self) -> torch.Tensor:
        """``(R, R, R)`` opacity of one voxel length at every grid corner (``[z, y, x]``)."""
        return 1.0 - torch.exp(-self.density(self.density_grid.grid[0]))


def render_coarse(model: CoarseModel, background: Background, origins: torch.Tensor,
                  dirs: torch.Tensor, samples: int, radius: float = 1.0, train: bool = True,
                  generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
    """Render rays through the density grid over the background.

    Args:
        model: the coarse model; background: radiance behind the object along each ray.
        origins: ``(R, 3)`` unit-frame ray origins; dirs: ``(R, 3)`` unit directions.
        samples: stratified samples per ray inside the bounding sphere of ``radius``.
        train: jitter the samples.

    Returns:
        ``rgb (R, 3)`` linear radiance and ``acc (R,)`` opacity.
    """
    near, far, hit = ray_sphere(origins, dirs, radius)
    rgb = background(origins, dirs)
    acc_all = torch.zeros(origins.shape[0], device=origins.device)
    idx = torch.nonzero(hit).squeeze(-1)
    if idx.numel() == 0:
        return {"rgb": rgb, "acc": acc_all}
    o, d, n0, f0 = origins[idx], dirs[idx], near[idx], far[idx]
    z = stratified(n0, f0, samples, jitter=train, generator=generator)
    pts = o[:, None] + z[..., None] * d[:, None]
    g = model.density_grid
    raw = trilinear_value_grad(g.grid[0], pts.reshape(-1, 3), g.bounds, with_grad=False)[0]
    step = ((f0 - n0) / samples / g.voxel)[:, None]
    alpha = 1.0 - torch.exp(-model.density(raw.view(z.shape)) * step)
    w = composite_weights(alpha)
    acc = w.sum(-1)
    # deferred colour: one feature lookup per ray, at its expected surface point
    x = (w[..., None] * pts).sum(1) / acc.clamp(min=1e-6)[:, None]
    surf = F.softplus(model.head(torch.cat([model.feat(x), d], -1)))
    rgb = rgb.index_put((idx,), acc[:, None] * surf + (1.0 - acc[:, None]) * rgb[idx])
    return {"rgb": rgb, "acc": acc_all.index_put((idx,), acc)}


def tv_loss(grid: torch.Tensor) -> torch.Tensor:
    """Mean squared difference of neighbouring values of a ``(D, H, W)`` grid (total variation)."""
    return ((grid[1:] - grid[:-1]) ** 2).mean() + ((grid[:, 1:] - grid[:, :-1]) ** 2).mean() \
        + ((grid[:, :, 1:] - grid[:, :, :-1]) ** 2).mean()


def train_coarse(model: CoarseModel, env: EnvLight, batch: Callable[[int], tuple],
                 loss_fn: Callable[[torch.Tensor, torch.Tensor], torch.Tensor], iters: int,
                 rays: int, samples: int, lr_grid: float = 0.1, lr_head: float = 1e-3,
                 lr_env: float = 3e-2, tv: float = 0.0, radius: float = 1.0,
                 generator: torch.Generator | None = None,
                 progress: Callable[[int, float], None] | None = None,
                 background: Background | None = None,
                 feedback: Callable[[torch.Tensor, torch.Tensor], None] | None = None
                 ) -> list[float]:
    """Fit the coarse model, the env map and the background to the photos; returns the
    per-step loss.

    Args:
        env: the learnable env map (trained at ``lr_env``). Only its finest level is read (the
            background), so no mip chain is built: at 256 rows that was 85 % of the map's cost.
        batch: ``batch(n)`` → ray origins, directions ``(n, 3)`` and target linear RGB ``(n, 3)``.
        loss_fn: photometric loss of predicted and target linear RGB.
        iters, rays, samples: steps, rays per step, samples per ray.
        lr_grid, lr_head, lr_env: Adam learning rates (grid values, colour head, env map).
        tv: weight of the total variation of the raw density.
        progress: called with (step, loss) after each step.
        background: radiance behind the object (default: ``env`` along the ray's direction).
        feedback: called with each batch's rendered and target linear RGB ``(n, 3)`` (the
            error-guided pixel sampler's measurement).
    """
    if background is None:
        def background(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
            return env.background(d)

    opt = torch.optim.Adam([dict(params=[model.density_grid.grid, model.feat.grid], lr=lr_grid),
                            dict(params=list(model.head.parameters()), lr=lr_head),
                            dict(params=[env.log_radiance], lr=lr_env)],
                           betas=(0.9, 0.99), eps=1e-15)
    env.release()  # no stale mip chain: the background reads the live map
    hist = []
    for it in range(iters):
        o, d, target = batch(rays)
        out = render_coarse(model, background, o, d, samples, radius, True, generator)
        loss = loss_fn(out["rgb"], target)
        if feedback is not None:
            feedback(out["rgb"].detach(), target)
        if tv > 0:
            loss = loss + tv * tv_loss(model.density_grid.grid[0])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        hist.append(float(loss.detach()))
        if progress is not None:
            progress(it, hist[-1])
    return hist
