"""Near-black and saturated photos through stage 1 (trainer, renderer, losses, env map).

The scene is the loaders' tiny off-centre sphere (tests/fixtures/scenes.py, 8 views, 40×32 px);
its linear images are multiplied by 1e-4 (near-black) or by 50 and clipped at 1 (saturated, as
an 8-bit camera clips). Checked: a few ``ShapeTrainer.train_step`` calls are never skipped
(finite loss), leave finite gradients, parameters and env map, and move the env map's background
the way the photos ask (darker / brighter) — and the saturation rule of
``voxnero.shape.losses.camera_response`` gives exactly zero colour gradient, through the whole
renderer, where the photo is clipped and the prediction is above it.
"""

from __future__ import annotations

import pytest
import torch

from tests.fixtures.scenes import make_blender
from tests.stability.stability_helpers import assert_finite_grads, tiny_model, tiny_shape_config
from voxnero.config import from_dict
from voxnero.data.detect import load_scene
from voxnero.shape import losses
from voxnero.shape.config import ShapeConfig
from voxnero.shape.renderer import render_rays
from voxnero.shape.trainer import ShapeTrainer

STEPS = 8


@pytest.fixture(scope="module")
def scene_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("img_extremes")
    make_blender(root, n={"train": 8}, w=40, h=32, seed=7)
    return root


def _variant(root, kind: str):
    sc = load_scene(root, splits=("train",))
    sp = sc.split("train")
    img = torch.as_tensor(sp.images)
    sp.images = img * 1e-4 if kind == "dark" else (img * 50.0).clamp(0.0, 1.0)
    return sc


def _cfg() -> ShapeConfig:
    return from_dict(ShapeConfig, {
        "iters": 100, "eval_every_s": 0, "preview_every": 0,
        "grid": {"res": [24], "upsample_at": []},
        "sampling": {"rays": 512, "coarse": 24, "fine": 8, "coarse_keep": 12},
        "light": {"env_height": 8},
        "optim": {"warmup": 1},
    })


@pytest.mark.parametrize("kind", ["dark", "saturated"])
def test_few_stage1_steps_stay_finite(scene_root, tmp_path, kind):
    """Every step keeps a finite loss (the trainer's non-finite skip never fires), finite
    gradients of every parameter, finite parameters and a finite positive env map; the
    env map's mean moves toward the photos (down for ×1e-4, up for saturated)."""
    sc = _variant(scene_root, kind)
    target = sc.split("train").images
    if kind == "dark":
        assert float(target.max()) <= 1e-4
    else:
        assert float((target >= 1.0).float().mean()) > 0.5  # most channels clipped
    msgs: list[str] = []
    tr = ShapeTrainer(_cfg(), sc, tmp_path, progress=False, log=msgs.append)
    env0 = float(tr.model.env.image().detach().mean())
    for i in range(STEPS):
        rec = tr.train_step()
        tr.step += 1
        assert torch.isfinite(torch.tensor(rec["loss"])), (kind, i, msgs)
        assert torch.isfinite(torch.tensor([rec["color"], rec["eik"]])).all()
        assert assert_finite_grads(tr.model, f"{kind} step {i}") >= 4
        for name, p in tr.model.named_parameters():
            assert torch.isfinite(p).all(), (kind, i, name)
        env = tr.model.env.image().detach()
        assert torch.isfinite(env).all() and (env > 0).all()
    assert not any("non-finite" in m for m in msgs), msgs
    env1 = float(tr.model.env.image().detach().mean())
    assert (env1 < env0) if kind == "dark" else (env1 > env0), (env0, env1)


def test_saturation_rule_zero_gradient_through_the_renderer():
    """Background rays (they miss the bounding sphere) and surface rays of a model whose env map
    is 5 (linear): the prediction is above 1 in every channel. Against a clipped photo (target
    1) the colour loss has exactly zero gradient for every parameter; against an unclipped
    photo (0.9) the same rays give a non-zero gradient (the rule is not a blanket clamp)."""
    cfg = tiny_shape_config()
    m = tiny_model(cfg, material=(0.9, 1.0, 0.2))
    with torch.no_grad():
        m.env.log_radiance.fill_(torch.log(torch.tensor(5.0)))
    x = torch.linspace(-0.5, 0.5, 6)
    o_hit = torch.stack([x, torch.zeros_like(x), torch.full_like(x, 3.0)], -1)
    d_hit = torch.tensor([0.0, 0.0, -1.0]).expand(6, 3)
    o_bg = torch.tensor([[0.0, 0.0, 3.0]]).expand(6, 3)
    d_bg = torch.nn.functional.normalize(torch.stack([x, torch.ones_like(x), 0.3 + x.abs()], -1),
                                         dim=-1)
    o, d = torch.cat([o_hit, o_bg]), torch.cat([d_hit, d_bg])

    def grads(target_value: float) -> list[torch.Tensor]:
        m.zero_grad(set_to_none=True)
        m.env.prepare()
        out = render_rays(m, o, d, 400.0, cfg, train=False)
        assert (out["rgb"] > 1.0).all(), out["rgb"]
        assert bool(out["hit"][:6].all()) and not bool(out["hit"][6:].any())
        losses.color_loss(out["rgb"], torch.full_like(out["rgb"], target_value)).backward()
        m.env.release()
        return [p.grad for p in m.parameters() if p.grad is not None]

    clipped = grads(1.0)
    assert all(float(g.abs().max()) == 0.0 for g in clipped)
    unclipped = grads(0.9)
    assert sum(float(g.abs().sum()) for g in unclipped) > 0
    assert all(torch.isfinite(g).all() for g in unclipped)
