"""The background decision of stage 1 (voxnero/shape/adaptive.py, ``decide_background``) picks
the near-background field only when the views disagree on background directions, and the
renderer composites it in front of the env map (voxnero/shape/renderer.py, ``background``)."""

from __future__ import annotations

from types import SimpleNamespace

import torch

from tests.data.test_distant import _split
from voxnero.config import resolve
from voxnero.shape import adaptive
from voxnero.shape.config import ShapeConfig
from voxnero.shape.renderer import ShapeModel, Switches, background


def _scene(near: bool):
    sp = _split(near=near)
    return SimpleNamespace(background="unknown", meta={}, split=lambda name: sp)


def test_near_only_with_parallax():
    mode, _, dec = adaptive.decide_background("auto", _scene(near=True))
    assert mode == "near" and dec.evidence["parallax_db"] >= adaptive.NEAR_PARALLAX_DB
    mode, _, dec = adaptive.decide_background("auto", _scene(near=False))
    assert mode == "distant" and dec.evidence["parallax_db"] < adaptive.NEAR_PARALLAX_DB
    mode, _, _ = adaptive.decide_background("distant", _scene(near=True))
    assert mode == "distant"  # the user's switch wins


def test_near_field_composited_in_front_of_the_env_map():
    cfg = resolve(ShapeConfig, "shape", "tiny", ["light.near_res=8", "light.near_samples=4"])
    model = ShapeModel(cfg, Switches(background="near"))
    assert "near_bg" in [g["name"] for g in model.param_groups(cfg)]
    o = torch.tensor([[0.0, 0.0, -3.0]]).expand(8, 3)
    d = torch.nn.functional.normalize(torch.randn(8, 3) * 0.3 + torch.tensor([0, 0, 1.0]), dim=-1)
    env = model.env.background(d)
    rgb, trans = model.near_bg(o, d)
    torch.testing.assert_close(background(model, d, o), rgb + trans[:, None] * env)
    with torch.no_grad():
        model.near_bg.grid[0] = -30.0  # transparent: the env map alone
    torch.testing.assert_close(background(model, d, o), env, rtol=1e-4, atol=1e-5)
    distant = ShapeModel(cfg, Switches(background="distant"))
    assert distant.near_bg is None
    torch.testing.assert_close(background(distant, d, o), distant.env.background(d))
