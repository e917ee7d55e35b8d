"""Sample placement along rays: bounding-sphere clip, stratified samples, importance samples.

A ray ``o + t·d`` (``d`` unit) is clipped to the bounding sphere; a coarse pass puts stratified
samples over the clipped segment, the SDF there (no autograd) gives NeuS weights, and the fine
samples are drawn from those weights (inverse CDF). Coarse and fine depths are merged and sorted so
that the rendered weights still see every crossing the coarse pass found (robustness against
missed surfaces) while most samples sit where the weight is.
"""

from __future__ import annotations

import torch


def ray_sphere(origins: torch.Tensor, dirs: torch.Tensor, radius: float
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Intersect rays with the centred sphere of ``radius``.

    Args:
        origins: ``(R, 3)``; dirs: ``(R, 3)`` unit directions.

    Returns:
        ``near (R,)``, ``far (R,)`` (``near ≥ 0``; both 0 for a miss) and ``hit (R,)`` bool.
    """
    b = (origins * dirs).sum(-1)
    c = (origins * origins).sum(-1) - radius * radius
    disc = b * b - c
    hit = disc > 0
    sq = torch.sqrt(torch.clamp(disc, min=0.0))
    near = torch.clamp(-b - sq, min=0.0)
    far = torch.clamp(-b + sq, min=0.0)
    hit = hit & (far > near)
    near = torch.where(hit, near, torch.zeros_like(near))
    far = torch.where(hit, far, torch.zeros_like(far))
    return near, far, hit


def ray_box(origins: torch.Tensor, dirs: torch.Tensor, bounds: torch.Tensor
            ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Intersect rays with an axis-aligned box (slab method).

    Args:
        origins: ``(R, 3)``; dirs: ``(R, 3)`` unit directions; bounds: ``(2, 3)`` min and max
            corners.

    Returns:
        ``near (R,)``, ``far (R,)`` (``near ≥ 0``; both 0 for a miss) and ``hit (R,)`` bool.
    """
    inv = 1.0 / torch.where(dirs.abs() < 1e-12, torch.full_like(dirs, 1e-12), dirs)
    t0 = (bounds[0] - origins) * inv
    t1 = (bounds[1] - origins) * inv
    near = torch.clamp(torch.minimum(t0, t1).amax(-1), min=0.0)
    far = torch.clamp(torch.maximum(t0, t1).amin(-1), min=0.0)
    hit = far > near
    zero = torch.zeros_like(near)
    return torch.where(hit, near, zero), torch.where(hit, far, zero), hit


def clip_rays(origins: torch.Tensor, dirs: torch.Tensor, radius: float,
              bounds: torch.Tensor | None = None
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The segment of each ray inside the centred sphere of ``radius`` and, if given, inside
    the box ``bounds`` (``(2, 3)``): ``near (R,)``, ``far (R,)``, ``hit (R,)`` as
    :func:`ray_sphere`. A box that contains the sphere changes nothing."""
    near, far, hit = ray_sphere(origins, dirs, radius)
    if bounds is None or bool((bounds[0] <= -radius).all() and (bounds[1] >= radius).all()):
        return near, far, hit
    nb, fb, hb = ray_box(origins, dirs, bounds)
    near, far = torch.maximum(near, nb), torch.minimum(far, fb)
    hit = hit & hb & (far > near)
    zero = torch.zeros_like(near)
    return torch.where(hit, near, zero), torch.where(hit, far, zero), hit


def stratified(near: torch.Tensor, far: torch.Tensor, n: int, jitter: bool = True,
               generator: torch.Generator | None = None) -> torch.Tensor:
    """``n`` stratified depths per ray in ``[near, far]``, ``(R, n)`` sorted.

    With ``jitter`` each sample is uniform in its stratum, else at the stratum centre.
    """
    r = near.shape[0]
    base = torch.arange(n, device=near.device, dtype=near.dtype)
    off = (torch.rand(r, n, device=near.device, generator=generator) if jitter
           else torch.full((r, n), 0.5, device=near.device))
    u = (base + off) / n
    return near[:, None] + (far - near)[:, None] * u


def sample_pdf(z: torch.Tensor, weights: torch.Tensor, n: int, jitter: bool = True,
               generator: torch.Generator | None = None) -> torch.Tensor:
    """Draw ``n`` depths per ray from the piecewise-constant pdf ``weights`` on the bins of ``z``.

    Args:
        z: ``(R, S)`` sorted bin edges.
        weights: ``(R, S − 1)`` non-negative bin weights (need not be normalised).
        n: samples per ray.
        jitter: random (else evenly spaced) CDF values.

    Returns:
        ``(R, n)`` sorted depths.
    """
    w = weights + 1e-5
    pdf = w / w.sum(-1, keepdim=True)
    cdf = torch.cat([torch.zeros_like(pdf[:, :1]), torch.cumsum(pdf, -1)], -1)
    cdf[:, -1] = 1.0
    r = z.shape[0]
    if jitter:
        u = (torch.arange(n, device=z.device, dtype=z.dtype)
             + torch.rand(r, n, device=z.device, generator=generator)) / n
    else:
        u = ((torch.arange(n, device=z.device, dtype=z.dtype) + 0.5) / n).expand(r, n)
    u = u.contiguous()
    idx = torch.searchsorted(cdf, u, right=True)
    lo = torch.clamp(idx - 1, 0, cdf.shape[1] - 2)
    hi = lo + 1
    c0 = torch.gather(cdf, 1, lo)
    c1 = torch.gather(cdf, 1, hi)
    z0 = torch.gather(z, 1, lo)
    z1 = torch.gather(z, 1, hi)
    t = ((u - c0) / torch.clamp(c1 - c0, min=1e-8)).clamp(0.0, 1.0)
    return z0 + t * (z1 - z0)


def merge_sorted(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Concatenate two ``(R, ·)`` depth sets and sort each row."""
    return torch.sort(torch.cat([a, b], -1), -1).values


def interval_lengths(z: torch.Tensor, near: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
    """Length of the interval each sample stands for (midpoint partition of ``[near, far]``).

    Args:
        z: ``(R, S)`` sorted depths; near, far: ``(R,)``.

    Returns:
        ``(R, S)`` lengths summing to ``far − near`` per ray.
    """
    mids = 0.5 * (z[:, 1:] + z[:, :-1])
    edges = torch.cat([near[:, None], mids, far[:, None]], -1)
    return edges[:, 1:] - edges[:, :-1]
