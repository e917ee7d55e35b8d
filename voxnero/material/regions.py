"""Does the surface hold two materials? A two-means split of the per-vertex material.

A metal and a dielectric on one object (the corpus bunny: a copper top, a terracotta bottom)
cannot both be fitted from one global base: every pixel trains the base, the metal's pixels
pull its metalness up, and the rough dielectric follows it into a rough metal that the photos
barely tell apart but a new light does (docs/STAGE2.md). So the trainer asks, once, whether the
vertices fall into two clearly different materials; if they do, each gets its own base
(:meth:`voxnero.material.field.VertexMaterial.split`) and both decide their metalness again.

The question is asked of albedo and roughness only (activated values, both in [0, 1]):
metalness is what the shared base may have got wrong for one of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class Split:
    """Outcome of :func:`two_materials`."""

    labels: Tensor
    """(V,) long: 0 or 1 per vertex (the larger cluster is 0)."""
    centres: Tensor
    """(2, C) cluster means of the features."""
    distance: float
    """Euclidean distance of the two centres (feature units)."""
    fraction: float
    """Share of the vertices in the smaller cluster."""
    accepted: bool
    """Whether the two clusters count as two materials."""


def two_means(x: Tensor, iters: int = 50) -> tuple[Tensor, Tensor]:
    """Lloyd's 2-means, started at the two extremes along the first principal axis.

    Args:
        x: (N, C) features, N >= 2.
        iters: at most this many assignment / update rounds.

    Returns:
        labels (N,) long in {0, 1}, centres (2, C). Deterministic for given ``x``.
    """
    mu = x.mean(0)
    u = torch.linalg.svd(x - mu, full_matrices=False).Vh[0]
    p = (x - mu) @ u
    c = torch.stack([x[p.argmin()], x[p.argmax()]])
    labels = torch.zeros(x.shape[0], dtype=torch.long, device=x.device)
    for _ in range(iters):
        new = torch.cdist(x, c).argmin(1)
        if _ and torch.equal(new, labels):
            break
        labels = new
        c = torch.stack([x[labels == k].mean(0) if bool((labels == k).any()) else c[k]
                         for k in range(2)])
    return labels, c


def two_materials(features: Tensor, min_distance: float, min_fraction: float) -> Split:
    """Split vertices into two materials when their features say so.

    Args:
        features: (V, C) per-vertex material features (activated albedo and roughness).
        min_distance: the centres must lie at least this far apart (feature units).
        min_fraction: and the smaller cluster must hold at least this share of the vertices.

    Returns:
        The :class:`Split` (labels relabelled so that cluster 0 is the larger one).
    """
    x = features.detach().float()
    if x.shape[0] < 2:
        z = torch.zeros(x.shape[0], dtype=torch.long, device=x.device)
        return Split(z, x.new_zeros(2, x.shape[1]), 0.0, 0.0, False)
    labels, c = two_means(x)
    share = float(labels.float().mean())
    if share > 0.5:
        labels, c, share = 1 - labels, c.flip(0), 1.0 - share
    dist = float(torch.linalg.norm(c[1] - c[0]))
    return Split(labels, c, dist, share, dist >= min_distance and share >= min_fraction)
