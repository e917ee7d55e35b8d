"""Tests of voxnero/cameras/error_pixels.py: the error-guided sampler of training pixels.

Closed forms: with ``frac = 0`` the draws are :func:`random_pixels`' own; with all the error in
one tile, that tile receives ``frac + (1 − frac) · area_share`` of the draws; a tile's running
error moves by ``decay`` of the gap to its batch mean; every pixel lies inside its tile and the
image, also for sizes that tiles do not divide.
"""

from __future__ import annotations

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.cameras.error_pixels import ErrorGuidedPixels
from voxnero.cameras.rays import random_pixels


def test_frac_zero_draws_the_uniform_pixels():
    s = ErrorGuidedPixels(5, 20, 30, tile=4, frac=0.0)
    cam, pix = s.draw(500, torch.Generator().manual_seed(3))
    s.feedback(torch.rand(500))
    cam2, pix2 = s.draw(500, torch.Generator().manual_seed(4))
    ref = random_pixels(500, 5, 20, 30, generator=torch.Generator().manual_seed(4))
    assert torch.equal(cam2, ref[0]) and torch.equal(pix2, ref[1])


def test_the_first_batch_is_uniform_then_the_wrong_tile_gets_its_share():
    n_cams, h, w, tile, frac = 4, 16, 16, 8, 0.5
    s = ErrorGuidedPixels(n_cams, h, w, tile=tile, frac=frac, decay=1.0)
    gen = torch.Generator().manual_seed(0)
    cam, pix = s.draw(4000, gen)
    ref = random_pixels(4000, n_cams, h, w, generator=torch.Generator().manual_seed(0))
    assert torch.equal(cam, ref[0])  # nothing measured yet: all uniform
    bad = 6  # photo 1, lower-left tile
    err = (s.tiles_of(cam, pix) == bad).float()
    s.feedback(err)
    assert s.err[bad] == 1.0 and float(s.err.sum()) == 1.0
    n = 200_000
    cam, pix = s.draw(n, gen)
    share = float((s.tiles_of(cam, pix) == bad).float().mean())
    expected = frac + (1 - frac) / (n_cams * 4)
    assert share == pytest.approx(expected, abs=4e-3)
    # inside the tile the draws are uniform: its 64 pixels each get about 1/64
    sel = s.tiles_of(cam, pix) == bad
    flat = (pix[sel].floor().long() * torch.tensor([1, w])).sum(-1)
    counts = torch.bincount(flat, minlength=h * w)
    counts = counts[counts > 0]
    assert len(counts) == tile * tile
    assert float(counts.float().std() / counts.float().mean()) < 0.05


def test_feedback_moves_a_tile_by_decay_of_the_gap():
    s = ErrorGuidedPixels(1, 8, 8, tile=4, frac=0.5, decay=0.25)
    s.draw(2, torch.Generator().manual_seed(0))
    s._last = torch.tensor([0, 0])
    s.feedback(torch.tensor([0.2, 0.4]))  # first measurement: every tile at the batch mean
    assert torch.allclose(s.err, torch.full((4,), 0.3))
    s.draw(3, torch.Generator().manual_seed(1))
    s._last = torch.tensor([1, 1, 2])
    s.feedback(torch.tensor([1.0, 0.0, 0.7]))
    assert torch.allclose(s.err, torch.tensor([0.3, 0.3 + 0.25 * (0.5 - 0.3),
                                               0.3 + 0.25 * (0.7 - 0.3), 0.3]))


@settings(max_examples=40, deadline=None)
@given(h=st.integers(1, 23), w=st.integers(1, 23), tile=st.integers(1, 9),
       seed=st.integers(0, 2**31 - 1), subpixel=st.booleans())
def test_pixels_lie_in_their_tile_and_the_image(h, w, tile, seed, subpixel):
    s = ErrorGuidedPixels(3, h, w, tile=tile, frac=0.7, subpixel=subpixel)
    gen = torch.Generator().manual_seed(seed)
    cam, pix = s.draw(64, gen)
    s.feedback(torch.rand(64, generator=gen))
    cam, pix = s.draw(256, gen)
    assert cam.min() >= 0 and cam.max() < 3
    assert (pix[:, 0] >= 0).all() and (pix[:, 0] < w).all()
    assert (pix[:, 1] >= 0).all() and (pix[:, 1] < h).all()
    if not subpixel:
        assert torch.equal(pix - 0.5, (pix - 0.5).floor())  # pixel centres
    t = s.tiles_of(cam, pix)
    assert t.min() >= 0 and t.max() < s.err.numel()


def test_state_round_trip_draws_the_same_pixels():
    a = ErrorGuidedPixels(2, 16, 16, tile=4, frac=0.6)
    gen = torch.Generator().manual_seed(7)
    a.draw(300, gen)
    a.feedback(torch.rand(300, generator=gen))
    b = ErrorGuidedPixels(2, 16, 16, tile=4, frac=0.6)
    b.load_state_dict(a.state_dict())
    ga, gb = torch.Generator().manual_seed(9), torch.Generator().manual_seed(9)
    ca, pa = a.draw(300, ga)
    cb, pb = b.draw(300, gb)
    assert torch.equal(ca, cb) and torch.equal(pa, pb)


@pytest.mark.parametrize("bad", [dict(tile=0), dict(frac=1.5), dict(decay=0.0)])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError):
        ErrorGuidedPixels(1, 8, 8, **bad)


def test_subpixel_points_cover_the_pixel_uniformly():
    """Both parts of a batch (uniform and error-guided) put their points uniformly inside the
    pixel: the fractional part has mean 1/2 and variance 1/12 per axis."""
    s = ErrorGuidedPixels(2, 8, 8, tile=4, frac=0.5, subpixel=True)
    gen = torch.Generator().manual_seed(0)
    s.draw(100, gen)
    s.feedback(torch.rand(100, generator=gen))
    _, pix = s.draw(40_000, gen)
    for part in (pix[:20_000], pix[20_000:]):
        f = part - part.floor()
        assert torch.allclose(f.mean(0), torch.tensor([0.5, 0.5]), atol=0.01)
        assert torch.allclose(f.var(0), torch.tensor([1 / 12, 1 / 12]), atol=0.005)
