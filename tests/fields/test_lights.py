"""Tests of voxnero/fields/lights.py's ``EnvLight``, the one learnable env map of both stages:
the clamp as a constructor argument, the state-dict key that checkpoints hold, the start from
a map, upsampling, smoothness, and the three stage-1 lookups against the render functions."""

from __future__ import annotations

import math

import torch

from voxnero.fields.lights import EnvLight
from voxnero.material.lights import LOG_MAX, LOG_MIN
from voxnero.render.latlong import envmap_lookup, pixel_dirs
from voxnero.render.mip import lookup_rough, mip_chain
from voxnero.render.sh import sh9_irradiance, sh9_project


def test_clamps_are_constructor_arguments():
    # stage 1: only an upper clamp (light.max_log_radiance); stage 2: LOG_MIN .. LOG_MAX
    s1 = EnvLight(4, 1.0, max_log=4.0)
    with torch.no_grad():
        s1.log_radiance[0, 0] = torch.tensor([10.0, -30.0, 0.0])
    assert torch.allclose(s1.image()[0, 0], torch.exp(torch.tensor([4.0, -30.0, 0.0])))
    s2 = EnvLight.from_image(torch.ones(4, 8, 3), LOG_MAX, LOG_MIN)
    with torch.no_grad():
        s2.log_radiance[0, 0] = torch.tensor([10.0, -30.0, 0.0])
    assert torch.allclose(s2.image()[0, 0], torch.exp(torch.tensor([LOG_MAX, LOG_MIN, 0.0])))
    assert s2.upsampled(8).max_log == LOG_MAX and s2.upsampled(8).min_log == LOG_MIN


def test_state_dict_key_is_log_radiance():
    # stage-1 checkpoints hold "env.log_radiance" (shape/run_files.py saves model.state_dict());
    # stage 2's checkpoint holds the tensor itself under "env" (material/trainer.py)
    env = EnvLight(8, 0.5)
    assert list(env.state_dict()) == ["log_radiance"]
    assert env.log_radiance.shape == (8, 16, 3) and env.height == 8
    assert torch.allclose(env.image(), torch.full((8, 16, 3), 0.5))


def test_from_image_lookup_and_upsampling_keep_the_map():
    H = 16
    d = pixel_dirs(H, 2 * H)
    base = 0.5 + 0.4 * d[..., :1] * torch.tensor([1.0, 0.5, 0.2]) + 0.3 * d[..., 2:3]
    env = EnvLight.from_image(base, LOG_MAX, LOG_MIN)
    assert torch.allclose(env.background(d), base, rtol=1e-4)
    up = env.upsampled(32)
    assert up.log_radiance.shape == (32, 64, 3)
    # a smooth map stays (nearly) the same function of direction, including across u = 0
    g = torch.Generator().manual_seed(1)
    q = torch.nn.functional.normalize(torch.randn(500, 3, generator=g), dim=-1)
    assert torch.allclose(up.background(q), env.background(q), rtol=0.02, atol=0.01)
    flat = EnvLight.from_image(torch.ones(4, 8, 3), LOG_MAX, LOG_MIN)
    assert float(flat.smoothness().detach()) < 1e-12


def test_stage_1_lookups_are_the_render_functions():
    g = torch.Generator().manual_seed(2)
    env = EnvLight(16, 0.5)
    with torch.no_grad():
        env.log_radiance.add_(torch.randn(16, 32, 3, generator=g))
    d = torch.nn.functional.normalize(torch.randn(50, 3, generator=g), dim=-1)
    r = torch.rand(50, 1, generator=g)
    img = env.image()
    env.prepare()
    assert torch.equal(env.background(d), envmap_lookup(img, d))
    assert torch.equal(env.specular(d, r), lookup_rough(mip_chain(img), d, r))
    assert torch.equal(env.diffuse(d), sh9_irradiance(sh9_project(img), d) / math.pi)
    env.release()
    assert env._chain is None and env._sh is None
    assert torch.equal(env.background(d), envmap_lookup(img, d))


def test_exact_irradiance_lights_no_face_turned_from_a_sun():
    # a small bright sun on a dim sky: the exact convolution gives the closed form
    # E(n) = E_sky + P * max(cos, 0) (P the sun's power), where order-2 SH rings: 9 % of P at
    # 90 degrees; and it is differentiable in the map (stage 1 learns the map through it)
    from voxnero.render.latlong import pixel_solid_angles

    H = 64
    img = torch.full((H, 2 * H, 3), 0.1)
    d = pixel_dirs(H, 2 * H)
    om = pixel_solid_angles(H, 2 * H)
    i, j = divmod(int(torch.argmax((d[..., 2] * 0.8 + d[..., 0] * 0.6).reshape(-1))), 2 * H)
    img[i, j] = 2000.0
    sd = d[i, j]
    power = float((img[i, j, 0] - 0.1) * om[i, j])
    ex, s9 = EnvLight.from_image(img, 10.0, irradiance="exact"), EnvLight.from_image(img, 10.0)
    perp = torch.nn.functional.normalize(torch.cross(sd, torch.tensor([0.0, 1.0, 0.0]), dim=0),
                                         dim=0)
    n = torch.stack([sd, perp, -sd])
    e_ex = ex.diffuse(n)[:, 0].detach() * math.pi
    e_s9 = s9.diffuse(n)[:, 0].detach() * math.pi
    sky = 0.1 * math.pi
    ref = torch.tensor([sky + power, sky, sky])
    # within 1.5 % of the sun's power (the bilinear table across the cosine's kink at 90 deg)
    assert ((e_ex - ref).abs() < 0.015 * power).all(), (e_ex, ref)
    assert float(e_s9[1] - sky) > 0.06 * power  # the ringing the exact table avoids
    ex.release()
    ex.diffuse(n).sum().backward()
    assert ex.log_radiance.grad is not None and float(ex.log_radiance.grad[i, j].abs().sum()) > 0
    assert ex.upsampled(32).irradiance == "exact"
