"""Tests of voxnero/shape/losses.py: closed forms and the saturation rule."""

from __future__ import annotations

import torch

from voxnero.fields.grid import grid_points, sphere_sdf_grid
from voxnero.shape import losses


def test_charbonnier_closed_form():
    p, t = torch.tensor([0.0, 0.3]), torch.tensor([0.1, 0.3])
    eps = 1e-3
    expect = ((0.01 + eps**2) ** 0.5 - eps + 0.0) / 2
    assert abs(float(losses.charbonnier(p, t, eps)) - expect) < 1e-7


def test_camera_response_clips_only_saturated_targets():
    pred = torch.tensor([[1.5, 1.5, 0.5]], requires_grad=True)
    target = torch.tensor([[1.0, 0.8, 0.5]])
    out = losses.camera_response(pred, target)
    assert out.tolist() == [[1.0, 1.5, 0.5]]
    loss = losses.color_loss(pred, target)
    loss.backward()
    g = pred.grad[0]
    assert g[0] == 0  # saturated and above: not an error
    assert g[1] > 0  # too bright where the photo is not saturated: pushed down


def test_eikonal_zero_for_unit_gradients():
    g = torch.nn.functional.normalize(torch.randn(100, 3), dim=-1)
    assert float(losses.eikonal(g)) < 1e-10
    assert abs(float(losses.eikonal(2 * g)) - 1.0) < 1e-5


def test_laplacian_of_plane_and_sphere():
    b = torch.tensor([[-1.0] * 3, [1.0] * 3])
    p = grid_points(33, b)
    plane = p[..., 0] * 0.6 + p[..., 1] * 0.8
    vox = 2 / 32
    assert float(losses.laplacian(plane, vox)) < 1e-8
    sph = sphere_sdf_grid(33, 1.0, 0.5)[0]
    r = p.norm(dim=-1)[1:-1, 1:-1, 1:-1]
    expect = float(((2 * vox / r.clamp(min=1e-3)) ** 2)[r > 0.2].mean())
    got = float(losses.laplacian(sph, vox))
    # the mean includes voxels near the centre where the discrete Laplacian differs
    assert 0.5 * expect < got < 3 * expect


def test_psnr_known_value():
    t = torch.full((10, 3), 0.5)
    p = t.clone()
    assert losses.psnr(p, t) > 100
