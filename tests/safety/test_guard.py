"""voxnero/safety/guard.py: a loss that stays non-finite stops stage 1 and stage 2 with the likely
cause; NaN state is never checkpointed."""

from __future__ import annotations

import pytest
import torch

from tests.safety.safety_helpers import blender_scene, run_cli, shape_argv
from voxnero.errors import TrainingError
from voxnero.safety.guard import MAX_NONFINITE_STEPS, NonFiniteGuard
from voxnero.shape import losses


def test_shape_stops_when_the_loss_stays_nan(tmp_path, capsys, monkeypatch):
    """Every step "non-finite loss, step skipped", then exit 0 with the untrained sphere written
    as the mesh (the issue's sampling.rays=0 row, whatever makes the loss NaN)."""
    scene = blender_scene(tmp_path / "scene")
    monkeypatch.setattr(losses, "color_loss", lambda *a, **k: torch.tensor(float("nan")))
    out = tmp_path / "out"
    rc, _, err = run_cli(shape_argv(scene, out, f"iters={MAX_NONFINITE_STEPS + 10}"), capsys)
    assert rc == 2, err
    assert f"non-finite (NaN/Inf) for {MAX_NONFINITE_STEPS} consecutive steps (0-" in err
    assert "likely cause: the settings (learning rates optim.lr_sdf=" in err and "fix:" in err
    assert not (out / "mesh.ply").exists()


def test_nan_state_is_never_checkpointed(tmp_path, capsys, monkeypatch):
    """A grid gone NaN was saved as the checkpoint that every re-run then resumed."""
    from voxnero.shape.trainer import CKPT, ShapeTrainer

    scene = blender_scene(tmp_path / "scene")
    real, calls = ShapeTrainer.train_step, {"n": 0}

    def poisoned(self):
        calls["n"] += 1
        rec = real(self)
        if calls["n"] == 3:
            with torch.no_grad():
                self.model.sdf.grid[0, 1, 1, 1] = float("nan")
        return rec

    monkeypatch.setattr(ShapeTrainer, "train_step", poisoned)
    out = tmp_path / "out"
    rc, _, err = run_cli(shape_argv(scene, out, "iters=8", "ckpt_every_s=0"), capsys)
    assert rc == 2 and "sdf.grid" in err and "NaN/Inf" in err, err
    ck = torch.load(out / CKPT, weights_only=False)
    assert ck["step"] == 2
    assert all(bool(torch.isfinite(t).all()) for t in ck["model"].values()
               if t.is_floating_point())


def test_material_stops_when_the_loss_stays_nan(tmp_path):
    """Stage 2 had no guard at all: NaN went through backward into every parameter."""
    from tests.material.stage2_scene import ring_cameras, sphere_geometry
    from voxnero.material.config import MaterialConfig
    from voxnero.material.surface import build_cache
    from voxnero.material.trainer import MaterialTrainer

    geom, cams = sphere_geometry(0.5, 12), ring_cameras(2, 12)
    cache = build_cache(geom, torch.full((2, 12, 12, 3), 0.5), cams, max_pixels=0)
    cfg = MaterialConfig(iters=MAX_NONFINITE_STEPS + 5, batch=16, bg_batch=16, log_every=10**6,
                         checkpoint_every=1)
    cfg.light.env_height = [8]
    tr = MaterialTrainer(cfg, geom, cache, log=lambda s: None)
    real = tr.loss_terms
    tr.loss_terms = lambda: {**real(), "object": torch.tensor(float("nan"), requires_grad=True)}
    with pytest.raises(TrainingError, match="lr_material=0.05"):
        tr.fit(tmp_path / "checkpoint.pt", progress=False)
    assert all(bool(torch.isfinite(p).all()) for p in tr.field.parameters())
    assert tr.step == MAX_NONFINITE_STEPS - 1  # the last one raised before it counted


def test_isolated_bad_steps_pass():
    guard = NonFiniteGuard("x", lambda: "cause", "fix", limit=3)
    for step, ok in enumerate([False, False, True, False, False, True]):
        guard.update(ok, step)
    with pytest.raises(TrainingError, match=r"3 consecutive steps \(6-8\); likely cause: cause"):
        for step in range(6, 9):
            guard.update(False, step)
