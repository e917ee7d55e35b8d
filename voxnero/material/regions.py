"""Does the surface hold two materials? A two-means split of the per-vertex material.

A metal and a dielectric on one object (the corpus bunny: a copper top, a terracotta bottom)
cannot both be fitted from one global base: every pixel trains the base, the metal's pixels
pull its metalness up, and the rough dielectric follows it into a rough metal that the photos
barely tell apart but a new light does (docs/STAGE2.md). So the trainer asks, once, whether the
vertices fall into two clearly different materials; if they do, each gets its own base
(:meth:`voxnero.material.field.VertexMaterial.split`) and both decide their metalness again.

The question is asked of the albedo's chromaticity and the roughness
(:func:`material_features`): metalness is what the shared base may have got wrong for one of
them, and brightness is what an albedo absorbs of a light still being learned.
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


def material_features(values: Tensor) -> Tensor:
    """Features of activated materials for :func:`two_materials`.

    Args:
        values: (V, 5) activated albedo RGB, metallic, roughness.

    Returns:
        (V, 4): albedo chromaticity RGB / (R + G + B) (sums to 1; brightness dropped) and
        roughness, all in [0, 1].
    """
    a = values[:, :3]
    return torch.cat([a / a.sum(1, keepdim=True).clamp_min(1e-6), values[:, 4:5]], 1)


def mesh_average(values: Tensor, edges: Tensor, rounds: int) -> Tensor:
    """Average per-vertex values with their mesh neighbours ``rounds`` times (each round: a
    vertex becomes the mean of itself and its neighbours), to quiet per-vertex noise before a
    split without moving a boundary by more than ``rounds`` edges.

    Args:
        values: (V, C); edges: (E, 2) long vertex pairs (each once); rounds: >= 0.

    Returns:
        (V, C).
    """
    v = values
    deg = torch.ones(v.shape[0], device=v.device).index_add_(
        0, edges.reshape(-1), torch.ones(edges.numel(), device=v.device))
    for _ in range(rounds):
        s = v.clone()
        s.index_add_(0, edges[:, 0], v[edges[:, 1]])
        s.index_add_(0, edges[:, 1], v[edges[:, 0]])
        v = s / deg[:, None]
    return v


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
        features: (V, C) per-vertex material features (:func:`material_features`).
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
