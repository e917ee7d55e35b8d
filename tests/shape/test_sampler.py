"""Tests of voxnero/shape/sampler.py: ray–sphere geometry, inverse-CDF sampling statistics."""

from __future__ import annotations

import torch

from voxnero.shape.sampler import interval_lengths, merge_sorted, ray_sphere, sample_pdf, stratified


def test_ray_sphere_closed_form():
    o = torch.tensor([[0.0, 0.0, -4.0], [0.0, 0.6, -4.0], [0.0, 2.0, -4.0], [0.0, 0.0, 0.0]])
    d = torch.tensor([[0.0, 0.0, 1.0]] * 4)
    near, far, hit = ray_sphere(o, d, 1.0)
    assert hit.tolist() == [True, True, False, True]
    assert torch.allclose(near[:2], torch.tensor([3.0, 4.0 - 0.8]), atol=1e-6)
    assert torch.allclose(far[:2], torch.tensor([5.0, 4.0 + 0.8]), atol=1e-6)
    assert near[3] == 0 and abs(float(far[3]) - 1.0) < 1e-6  # origin inside


def test_stratified_in_strata():
    near, far = torch.tensor([1.0, 2.0]), torch.tensor([3.0, 6.0])
    z = stratified(near, far, 8, generator=torch.Generator().manual_seed(0))
    k = torch.floor((z - near[:, None]) / (far - near)[:, None] * 8)
    assert torch.equal(k, torch.arange(8.0).expand(2, 8))


def test_sample_pdf_matches_histogram():
    # piecewise-constant pdf on [0, 4]: bin masses 0.1, 0.6, 0.0, 0.3
    z = torch.tensor([[0.0, 1.0, 2.0, 3.0, 4.0]])
    w = torch.tensor([[0.1, 0.6, 0.0, 0.3]])
    n = 20000
    s = sample_pdf(z, w, n, generator=torch.Generator().manual_seed(1))
    hist = torch.histc(s, bins=4, min=0, max=4) / n
    # 1e-5 floor per bin is negligible; stratified draws: error ≪ 1/sqrt(n)
    assert torch.allclose(hist, w[0], atol=2e-3)
    assert torch.all(s[:, 1:] >= s[:, :-1])


def test_interval_lengths_partition_and_merge():
    z = merge_sorted(torch.tensor([[0.5, 1.5]]), torch.tensor([[1.0, 0.2]]))
    assert torch.equal(z, torch.tensor([[0.2, 0.5, 1.0, 1.5]]))
    dl = interval_lengths(z, torch.tensor([0.0]), torch.tensor([2.0]))
    assert abs(float(dl.sum()) - 2.0) < 1e-6
    assert torch.allclose(dl, torch.tensor([[0.35, 0.4, 0.5, 0.75]]))
