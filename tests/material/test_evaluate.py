"""Whole-view renders of stage 2 (``voxnero/material/evaluate.py``): the box filter of a pixel."""

from __future__ import annotations

import pytest
import torch

from tests.material.stage2_scene import ring_cameras, sphere_geometry
from voxnero.material.evaluate import render_view
from voxnero.material.field import VertexMaterial
from voxnero.material.render import Strategies


def _render(size: int, subpixels: int, spp: Strategies, seed: int = 0):
    geom = sphere_geometry(0.5, 40)
    field = VertexMaterial(geom, 0.1, 0.0, 0.5)  # dark rough dielectric: ~0.15 on a sky of 1
    env = torch.ones(16, 32, 3)
    cams = ring_cameras(1, size=size)
    return render_view(geom, field, env, cams, 0, spp, indirect=False, visibility=False,
                       generator=torch.Generator().manual_seed(seed), subpixels=subpixels)


def test_box_filter_matches_a_supersampled_render():
    """A pixel is the mean radiance over its footprint (the data's box filter): a 16-px view with
    16 jittered points per pixel must match a 128-px view rendered at pixel centres and averaged
    over 8 x 8 blocks; a pixel-centre render of the 16-px view must not (silhouette pixels)."""
    base, k = 16, 8
    box = _render(base, 16, Strategies(16, 16, 16))
    centre = _render(base, 1, Strategies(1, 1, 1))
    fine = _render(base * k, 1, Strategies(2, 2, 2), seed=1)
    ref = fine["rgb"].reshape(base, k, base, k, 3).mean((1, 3))
    cover = fine["hit"].float().reshape(base, k, base, k).mean((1, 3))
    edge = (cover > 0.1) & (cover < 0.9)
    assert int(edge.sum()) >= 12
    err_box = (box["rgb"] - ref)[edge].abs().mean()
    err_centre = (centre["rgb"] - ref)[edge].abs().mean()
    # a 4 x 4 stratified pattern gets the coverage to a fraction of 1/16 (x contrast 0.85);
    # MC noise of the shading is small (constant sky: the diffuse cosine samples are exact).
    # Measured: 0.031 (box) against 0.265 (pixel centres).
    assert err_box < 0.05, float(err_box)
    assert err_centre > 3 * err_box, (float(err_centre), float(err_box))
    # pixels wholly on the sky are the sky; wholly on the object, the reference within MC noise
    sky = cover == 0
    torch.testing.assert_close(box["rgb"][sky], torch.ones_like(box["rgb"][sky]))
    inner = cover == 1
    assert (box["rgb"] - ref)[inner].abs().mean() < 0.02
    # material maps and the hit mask are read at pixel centres, whatever the subpixel count
    assert torch.equal(box["hit"], centre["hit"])
    torch.testing.assert_close(box["roughness"], centre["roughness"])


def test_one_subpixel_is_the_pixel_centre_and_samples_are_split():
    """subpixels=1 reproduces the pixel-centre render bit for bit (same seed); counts that do
    not divide among the subpixels still give finite renders (a subpixel may get no sample of
    one strategy; there are never more subpixels than the largest count)."""
    a = _render(12, 1, Strategies(3, 3, 3), seed=4)
    b = _render(12, 1, Strategies(3, 3, 3), seed=4)
    assert torch.equal(a["rgb"], b["rgb"])
    c = _render(12, 4, Strategies(3, 0, 1), seed=4)  # 3 subpixels: cos 1 each, env in one
    assert torch.isfinite(c["rgb"]).all()
    with pytest.raises(ValueError, match="subpixels"):
        _render(12, 0, Strategies(3, 3, 3))


def test_subpixels_share_one_stratified_pattern_per_pixel():
    """Splitting a pixel's samples among its subpixels must not cost noise: the subpixels get
    one rotated Hammersley pattern per pixel dealt out (sample j to subpixel j mod K). With
    independent 2-point patterns per subpixel the torus evaluation lost 1 dB at 8 spp; here
    the seed-to-seed noise of pixels away from the silhouette must stay within 30 % of the
    pixel-centre render's (what is left is the real variation over the footprint of a 16-px
    sphere). Measured: 0.0148 against 0.0129."""
    def noise(subpixels):
        a = _render(16, subpixels, Strategies(4, 4, 4), seed=1)
        b = _render(16, subpixels, Strategies(4, 4, 4), seed=2)
        h = a["hit"]
        p = torch.nn.functional.pad(h[None, None].float(), (1, 1, 1, 1))[0, 0] > 0
        inner = h & p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:]
        assert int(inner.sum()) >= 20
        return (a["rgb"] - b["rgb"])[inner].abs().mean()

    n1, n4 = noise(1), noise(4)
    assert n1 > 0
    assert n4 < 1.3 * n1, (float(n4), float(n1))


def test_indirect_true_is_decided_like_stage2_from_the_visible_points():
    """``indirect=True`` (materials.json's decisions.indirect) becomes the traced model where
    the visible points see much of the object (two facing plates: about half of the cosine
    rays from the lower one hit the upper one) and the split-sum one where they see little
    (a convex sphere), as ``trainer.decide_secondary`` decides it."""
    from tests.material.test_paths import _plates
    from voxnero.material.evaluate import indirect_model

    plates = _plates()
    n = 512
    tri = torch.zeros(n, dtype=torch.long)
    bary = torch.distributions.Dirichlet(torch.ones(3)).sample((n,))
    assert indirect_model(True, plates, (tri, bary)) == "traced"
    sphere = sphere_geometry()
    assert indirect_model(True, sphere, (tri, bary)) == "splitsum"
    assert indirect_model(True) == "traced" and indirect_model(False) == "off"
    assert indirect_model("splitsum", plates, (tri, bary)) == "splitsum"


def _noisy(value: float, sigma: float, seed: int = 0, size: int = 64):
    """A render function: a constant linear image plus Gaussian noise of std ``sigma`` per
    pass (independent passes), and a counter of the calls."""
    g = torch.Generator().manual_seed(seed)
    calls = []

    def render():
        calls.append(1)
        rgb = value + sigma * torch.randn(size, size, 3, generator=g)
        return {"rgb": rgb, "hit": torch.ones(size, size, dtype=torch.bool)}
    return render, calls


def test_converged_render_estimates_its_noise_and_stops_at_the_share():
    """Photo 0.2 (linear), model 0.21 (bias 0.01), noise σ = 0.02 per pass: in sRGB the
    error² is (g'·0.01)² and the noise of the mean of k passes (g'·0.02)²/k, so noise ≤ 0.1 ×
    (bias² + noise) first holds at k = 37 (4/k ≤ 0.1 (1 + 4/k)): with 8 passes at most, all 8
    run and the estimated noise PSNR matches the closed form within 0.5 dB; with a bias of 0.05,
    4/25/k ≤ 0.1 (1 + 4/25/k) holds from k = 2, so it stops after 2 passes."""
    import math

    from voxnero.io.color import srgb_slope
    from voxnero.material.evaluate import render_converged

    target = torch.full((64, 64, 3), 0.2)
    mask = torch.ones(64, 64, dtype=torch.bool)
    render, calls = _noisy(0.21, 0.02)
    out, info = render_converged(render, target, mask, max_passes=8, noise_share=0.1)
    assert info["passes"] == 8 and len(calls) == 8
    expect = -10 * math.log10(float(srgb_slope(torch.tensor(0.21))) ** 2 * 0.02 ** 2 / 8)
    assert abs(info["noise_psnr"] - expect) < 0.5, (info, expect)
    assert abs(float(out["rgb"].mean()) - 0.21) < 1e-3  # the mean of the passes
    assert float(out["rgb"].std()) < 0.02 / math.sqrt(8) * 1.1

    render, calls = _noisy(0.25, 0.02, seed=1)
    _, info = render_converged(render, target, mask, max_passes=8, noise_share=0.1)
    assert info["passes"] == 2 and len(calls) == 2, info

    render, calls = _noisy(0.25, 0.02, seed=2)
    _, info = render_converged(render, target, mask, max_passes=1)
    assert info["passes"] == 1 and len(calls) == 1 and math.isnan(info["noise_psnr"])
