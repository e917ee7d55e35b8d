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
