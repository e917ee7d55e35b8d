"""Tests of the mask-free visual hull (voxnero/shape/bg_votes.py) and the hull's growth into
what the photos show as object (voxnero/shape/hull.grow_seen_as_object), on photos of a sphere
drawn in closed form over a smooth background: the background pixels are the complement of
the sphere's exact outline, the sphere's points are never seen against the background, and a
hull that lost the sphere's upper half (a mirror's density below its shiny face) grows back to
the sphere without growing past it."""

from __future__ import annotations

import math

import numpy as np
import torch

from voxnero.cameras.cameras import Cameras, look_at_opencv
from voxnero.cameras.rays import pixel_centers, pixel_rays
from voxnero.fields.grid import grid_points
from voxnero.shape import bg_votes, hull

R = 0.4
"""The sphere's radius (unit frame, centre at the origin)."""
H = W = 48
OBJECT = torch.tensor([0.8, 0.3, 0.1])


def _background(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """A smooth sky: linear radiance by direction, never the object's colour."""
    return 0.2 + 0.15 * (d + 1.0) * torch.tensor([0.3, 0.6, 1.0])


def _photos(n: int = 24) -> tuple[Cameras, torch.Tensor, torch.Tensor]:
    """``n`` cameras on a sphere of radius 3 (two rings and the poles' neighbours) and their
    photos ``(n, H, W, 3)``, with the exact outline masks ``(n, H, W)``."""
    eyes = []
    for k in range(n):
        el = (-0.6, 0.0, 0.6, 1.2)[k % 4]
        az = 2 * math.pi * k / n
        eyes.append([3 * math.cos(el) * math.cos(az), 3 * math.cos(el) * math.sin(az),
                     3 * math.sin(el)])
    f = 0.5 * W / math.tan(math.radians(20))
    K = torch.tensor([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    cams = Cameras(K, torch.tensor(look_at_opencv(np.array(eyes)), dtype=torch.float32), W, H)
    pix = pixel_centers(H, W).reshape(-1, 2)
    photos, inside = [], []
    for c in range(n):
        o, d = pixel_rays(cams, torch.full((pix.shape[0],), c, dtype=torch.long), pix)
        b = (o * d).sum(-1)
        hit = b * b - ((o * o).sum(-1) - R * R) > 0
        photos.append(torch.where(hit[:, None], OBJECT, _background(o, d)).view(H, W, 3))
        inside.append(hit.view(H, W))
    return cams, torch.stack(photos), torch.stack(inside)


def test_the_background_pixels_are_the_complement_of_the_outline():
    cams, photos, outline = _photos()
    masks = bg_votes.background_pixels(cams, photos, _background)
    assert torch.equal(masks, ~outline)


def test_the_sphere_is_never_seen_against_the_background_and_far_points_mostly_are():
    cams, photos, _ = _photos()
    masks = bg_votes.background_pixels(cams, photos, _background)
    g = torch.Generator().manual_seed(0)
    dirs = torch.nn.functional.normalize(torch.randn(500, 3, generator=g), dim=-1)
    inner = dirs * (0.9 * R) * torch.rand(500, 1, generator=g)
    assert float(bg_votes.background_ratio(cams, masks, inner).max()) == 0.0
    far = dirs * 0.85  # outside the sphere by more than its radius
    assert float(bg_votes.background_ratio(cams, masks, far).min()) > 0.5
    # a point no camera sees counts as free space
    assert float(bg_votes.background_ratio(cams, masks, torch.tensor([[0.0, 0.0, 40.0]]))) == 1.0


def test_a_hull_without_its_upper_half_grows_back_to_the_sphere_only():
    cams, photos, _ = _photos()
    masks = bg_votes.background_pixels(cams, photos, _background)
    res, bound = 40, 0.6
    bounds = torch.tensor([[-bound] * 3, [bound] * 3])
    corners = grid_points(res, bounds).reshape(-1, 3)
    r = corners.norm(dim=-1).view(res, res, res).numpy()
    z = corners[:, 2].view(res, res, res).numpy()
    truth = r < R
    lower = truth & (z < -0.05)  # the density's hull: the upper half lost

    def ratio_of(sel: np.ndarray) -> np.ndarray:
        pts = corners[torch.from_numpy(np.flatnonzero(sel))]
        return bg_votes.background_ratio(cams, masks, pts).numpy()

    voxel = 2 * bound / (res - 1)
    grow = int(math.ceil((R + 0.05) / voxel))
    grown, ev = hull.grow_seen_as_object(lower, ratio_of, grow)
    assert (grown & truth).sum() / truth.sum() > 0.97 > (lower & truth).sum() / truth.sum()
    # nothing grows more than about a voxel past the sphere (the photos' pixel rounding)
    assert r[grown].max() < R + 1.5 * voxel
    assert ev["added"] > 0 and 0.0 <= ev["threshold"] <= 1.0
    # grow = 0 leaves the hull as it is
    same, ev0 = hull.grow_seen_as_object(lower, ratio_of, 0)
    assert same is lower and ev0["added"] == 0


def test_the_growth_threshold_is_the_quantile_of_the_cores_ratios_and_a_lower_one_adds_less():
    """``quantile`` (``coarse.bg_quantile``, 0.9 at `preview`): the threshold is that quantile
    of the ratios over the solid's eroded core, and only shell corners at or below it grow."""
    n = 24
    idx = np.indices((n, n, n)).transpose(1, 2, 3, 0).reshape(-1, 3)
    ratio = np.random.default_rng(1).uniform(0.0, 1.0, n ** 3)  # one ratio per corner

    def ratio_of(sel: np.ndarray) -> np.ndarray:
        return ratio[np.flatnonzero(sel)]

    inside = np.zeros((n, n, n), bool)
    inside[6:18, 6:18, 6:18] = True
    core = np.zeros_like(inside)
    core[8:16, 8:16, 8:16] = True  # eroded by 2
    shell = np.zeros_like(inside)
    shell[5:19, 5:19, 5:19] = True
    shell &= ~inside
    shell &= (np.abs(idx.reshape(n, n, n, 3) - 11.5) > 6.0).sum(-1) == 1  # 6-neighbours only
    added = {}
    for q in (0.95, 0.9):
        grown, ev = hull.grow_seen_as_object(inside, ratio_of, 1, quantile=q)
        assert ev["threshold"] == round(float(np.quantile(ratio[core.ravel()], q)), 4)
        assert ev["shell"] == int(shell.sum())
        assert ev["added"] == int((ratio[shell.ravel()] <= np.quantile(ratio[core.ravel()], q))
                                  .sum())
        assert (grown & ~inside).sum() > 0 and not (grown & ~(inside | shell)).any()
        added[q] = ev["added"]
    assert 0 < added[0.9] < added[0.95]
