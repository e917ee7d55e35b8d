"""Tests of voxnero/eval/images.py against closed forms and scikit-image's SSIM."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from skimage.metrics import structural_similarity

from voxnero.eval.images import fit_channel_scale, mae, psnr, ssim, ssim_map


def smooth_image(h=128, w=128, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    img = np.stack([0.5 + 0.3 * np.sin(6 * x + k) * np.cos(4 * y - k) for k in range(3)], -1)
    return np.clip(img + 0.02 * rng.normal(size=img.shape), 0.05, 0.95)


@pytest.mark.parametrize("sigma", [0.005, 0.02, 0.04])
def test_psnr_of_gaussian_noise(sigma):
    gt = smooth_image(256, 256)
    rng = np.random.default_rng(1)
    noisy = gt + rng.normal(0, sigma, gt.shape)  # no clipping: values stay inside [0, 1]
    # 196 608 samples: the sample variance is within ~0.3 % of σ² (±0.015 dB, 3 std)
    assert psnr(noisy, gt) == pytest.approx(10 * math.log10(1 / sigma**2), abs=0.05)
    assert psnr(torch.from_numpy(noisy).float(), torch.from_numpy(gt).float()) == pytest.approx(
        10 * math.log10(1 / sigma**2), abs=0.05)


def test_psnr_identical_is_inf_and_mask():
    gt = smooth_image()
    assert psnr(gt, gt.copy()) == math.inf
    pred = gt.copy()
    pred[:64] += 0.1  # error only in the top half
    mask = np.zeros(gt.shape[:2], bool)
    mask[64:] = True
    assert psnr(pred, gt, mask=mask) == math.inf
    assert psnr(pred, gt, mask=~mask) == pytest.approx(20.0, abs=1e-9)  # 10 log10(1 / 0.01)
    assert psnr(pred, gt) == pytest.approx(10 * math.log10(1 / 0.005), abs=1e-9)
    with pytest.raises(ValueError, match="selects no pixel"):
        psnr(pred, gt, mask=np.zeros_like(mask))


def test_ssim_identical_is_one_and_matches_skimage():
    gt = smooth_image(96, 96)
    assert ssim(gt, gt.copy()) == pytest.approx(1.0, abs=1e-6)  # kornia adds eps = 1e-12
    rng = np.random.default_rng(2)
    pred = np.clip(gt + rng.normal(0, 0.05, gt.shape), 0, 1)
    ours = float(ssim_map(pred, gt, padding="valid").mean())
    ref = structural_similarity(pred, gt, channel_axis=-1, data_range=1.0, gaussian_weights=True,
                                sigma=1.5, use_sample_covariance=False)
    assert ours == pytest.approx(ref, abs=2e-3)
    assert 0.3 < ssim(pred, gt) < 0.99


def test_ssim_batch_and_mask():
    gt = np.stack([smooth_image(64, 64, s) for s in range(2)])
    pred = gt.copy()
    pred[1] = 1 - pred[1]
    mask = np.zeros(gt.shape[:3], bool)
    mask[0] = True
    assert ssim(pred, gt, mask=mask) == pytest.approx(1.0, abs=1e-6)  # kornia adds eps = 1e-12
    assert ssim(pred, gt) < 0.9


@settings(max_examples=25, deadline=None)
@given(s=st.tuples(*[st.floats(0.05, 20.0)] * 3), seed=st.integers(0, 1000))
def test_channel_scale_recovers_known_scale(s, seed):
    rng = np.random.default_rng(seed)
    pred = rng.uniform(0.01, 1.0, (32, 32, 3))
    gt = pred * np.asarray(s)
    mask = rng.uniform(size=(32, 32)) > 0.3
    gt_bad = gt.copy()
    gt_bad[~mask] = 123.0  # outside the mask: ignored
    assert np.allclose(fit_channel_scale(pred, gt_bad, mask), s, rtol=1e-10)


def test_channel_scale_least_squares_and_torch():
    rng = np.random.default_rng(3)
    pred = rng.uniform(0.1, 1.0, (64, 64, 3))
    gt = pred * np.array([0.5, 2.0, 1.5]) + rng.normal(0, 0.01, pred.shape)
    s = fit_channel_scale(torch.from_numpy(pred), torch.from_numpy(gt))
    assert isinstance(s, torch.Tensor) and s.shape == (3,)
    # independent: numpy lstsq per channel
    ref = [np.linalg.lstsq(pred[..., c].reshape(-1, 1), gt[..., c].ravel(), rcond=None)[0][0]
           for c in range(3)]
    assert np.allclose(s.numpy(), ref, rtol=1e-5)


def test_channel_scale_clip_ignores_highlights_the_target_cannot_show():
    """A glint at 50× the 8-bit ceiling where the photo shows 0.5: the plain least-squares
    scale collapses toward 0, the clip-aware one recovers the true scale exactly."""
    rng = np.random.default_rng(7)
    s_true = np.array([0.8, 1.1, 1.3])
    pred = rng.uniform(0.01, 0.7, (48, 48, 3))
    gt = pred * s_true
    pred[:2, :3] = 50.0  # six glint pixels (0.3 % of the image) that the photo lacks
    gt[:2, :3] = 0.5
    plain = fit_channel_scale(pred, gt)
    assert np.all(plain < 0.5 * s_true)
    assert np.allclose(fit_channel_scale(pred, gt, clip=1.0), s_true, rtol=1e-12)


def test_channel_scale_clip_without_clipped_pixels_is_least_squares():
    rng = np.random.default_rng(8)
    pred = rng.uniform(0.0, 0.5, (32, 32, 3))
    gt = pred * 1.2 + rng.normal(0, 0.01, pred.shape)
    assert np.allclose(fit_channel_scale(pred, gt, clip=1.0), fit_channel_scale(pred, gt))


def test_channel_scale_clip_ignores_black_render_pixels():
    """A render pixel of exactly 0 (a shadow) costs the same at every scale: the fit is the
    one without it, finite."""
    rng = np.random.default_rng(9)
    pred = rng.uniform(0.1, 0.5, (16, 16, 3))
    gt = pred * np.array([1.2, 0.9, 1.1])
    black = pred.copy()
    black[0, :4] = 0.0
    keep = np.ones((16, 16), bool)
    keep[0, :4] = False
    s = fit_channel_scale(black, gt, clip=1.0)
    assert np.all(np.isfinite(s))
    assert np.allclose(s, fit_channel_scale(pred, gt, keep, clip=1.0), rtol=1e-12)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), glints=st.integers(0, 40), level=st.floats(1.0, 1e4))
def test_channel_scale_clip_minimises_the_clipped_error(seed, glints, level):
    """The fit minimises Σ (min(s·pred, 1) − gt)² over targets below 0.99: no scale on a
    dense grid and no nearby scale compares better (brute force, independent of the fit)."""
    rng = np.random.default_rng(seed)
    pred = rng.uniform(0.0, 1.2, (24, 24, 3))
    gt = np.clip(pred * rng.uniform(0.5, 1.5, 3) + rng.normal(0, 0.05, pred.shape), 0, 1)
    idx = rng.integers(0, 24, (glints, 2))
    pred[idx[:, 0], idx[:, 1]] = level
    s = fit_channel_scale(pred, gt, clip=1.0)
    ok = gt < 0.99

    def err(scale):
        return (((np.minimum(pred * scale, 1.0) - gt) ** 2) * ok).sum((0, 1))

    e0 = err(s)
    for f in (1 - 1e-3, 1 + 1e-3):
        assert np.all(e0 <= err(s * f) + 1e-9)
    best = np.min(np.stack([err(np.full(3, x)) for x in np.linspace(0.0, 4.0, 4001)]), 0)
    assert np.all(e0 <= best + 1e-9)


def test_channel_scale_clip_finds_the_best_scale_with_glints():
    """Glints and fireflies over a fitted image: the fit is the brute-force minimum of the
    clipped error over a dense grid of scales."""
    rng = np.random.default_rng(11)
    pred = rng.uniform(0.0, 0.9, (40, 40, 3))
    gt = np.clip(pred * np.array([0.9, 1.0, 1.2]) + rng.normal(0, 0.03, pred.shape), 0, 1)
    idx = rng.integers(0, 40, (12, 2))
    pred[idx[:, 0], idx[:, 1]] = rng.uniform(5, 500, (12, 1))
    s = fit_channel_scale(pred, gt, clip=1.0)
    ok = gt < 0.99

    def err(scale):
        return (((np.minimum(pred * scale, 1.0) - gt) ** 2) * ok).sum((0, 1))

    best = np.min(np.stack([err(np.full(3, x)) for x in np.linspace(0.0, 3.0, 3001)]), 0)
    assert np.all(err(s) <= best + 1e-9)
    assert np.all(np.abs(s / np.array([0.9, 1.0, 1.2]) - 1) < 0.02)


def test_mae():
    a = np.zeros((4, 4))
    b = np.zeros((4, 4))
    b[0, 0] = 1.6
    b[3, 3] = -0.4
    assert mae(a, b) == pytest.approx(2.0 / 16)
    m = np.zeros((4, 4), bool)
    m[0] = True
    assert mae(a, b, m) == pytest.approx(1.6 / 4)
    with pytest.raises(ValueError, match="differ in shape"):
        mae(a, np.zeros((4, 5)))
