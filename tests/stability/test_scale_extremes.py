"""Tiny and huge objects: the same scene with its input frame scaled by 1e-3 and 1e3.

A Blender-format scene (tests/fixtures/scenes.py: an off-centre sphere seen by 8 cameras at
40×32 px, rendered independently of the loaders) is written three times with every camera
centre multiplied by k ∈ {1e-3, 1, 1e3} and the *same* images (a scaled world looks the same).
Checked against the unscaled copy: the normalisation maps all three to the same unit-frame
cameras (float tolerance), a short stage-1 run through ``ShapeTrainer.run`` (the trainer's
public entry point) gives the same loss curve, and the mesh written in the input frame scales
back (bounding box ratio k).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from tests.fixtures.scenes import make_blender
from voxnero.config import from_dict
from voxnero.data.detect import load_scene
from voxnero.shape.config import ShapeConfig
from voxnero.shape.trainer import ShapeTrainer

SCALES = (1e-3, 1.0, 1e3)
STEPS = 30


@pytest.fixture(scope="module")
def scaled_roots(tmp_path_factory):
    """``{k: scene folder}`` of the same scene with camera centres scaled by k."""
    base = tmp_path_factory.mktemp("scale_base")
    make_blender(base, n={"train": 8}, w=40, h=32, seed=5)
    roots = {}
    for k in SCALES:
        root = tmp_path_factory.mktemp(f"scale_{k:g}")
        shutil.copytree(base / "train", root / "train")
        meta = json.loads((base / "transforms_train.json").read_text())
        for fr in meta["frames"]:
            m = np.asarray(fr["transform_matrix"], dtype=np.float64)
            m[:3, 3] *= k
            fr["transform_matrix"] = m.tolist()
        (root / "transforms_train.json").write_text(json.dumps(meta))
        roots[k] = root
    return roots


@pytest.fixture(scope="module")
def scenes(scaled_roots):
    return {k: load_scene(r, splits=("train",)) for k, r in scaled_roots.items()}


def test_normalisation_gives_the_same_unit_frame(scenes):
    """Scale and centre follow k exactly (float64); unit-frame cameras agree to float32."""
    ref = scenes[1.0]
    cr = ref.split("train").cameras
    for k, sc in scenes.items():
        assert sc.norm.scale == pytest.approx(k * ref.norm.scale, rel=1e-9)
        np.testing.assert_allclose(sc.norm.center, k * ref.norm.center, rtol=1e-9,
                                   atol=1e-12 * k)
        c = sc.split("train").cameras
        torch.testing.assert_close(c.c2w.float(), cr.c2w.float(), atol=2e-6, rtol=0)
        torch.testing.assert_close(c.K, cr.K)
        assert torch.equal(sc.split("train").images, ref.split("train").images)


def _cfg() -> ShapeConfig:
    return from_dict(ShapeConfig, {
        "iters": STEPS, "eval_every_s": 0, "preview_every": 0, "mesh_res": 40,
        "ckpt_every_s": 1e9,
        "grid": {"res": [24], "upsample_at": []},
        "sampling": {"rays": 256, "coarse": 24, "fine": 8, "coarse_keep": 12},
        "light": {"env_height": 8},
    })


@pytest.fixture(scope="module")
def runs(scenes, tmp_path_factory):
    """``{k: (losses per step, mesh vertices in the input frame)}`` after ``STEPS`` steps."""
    import open3d as o3d

    out = {}
    for k, sc in scenes.items():
        d = tmp_path_factory.mktemp(f"run_{k:g}")
        path = ShapeTrainer(_cfg(), sc, d, progress=False, log=lambda s: None).run()
        recs = [json.loads(x) for x in (d / "log.jsonl").read_text().splitlines()]
        losses = np.array([r["loss"] for r in recs if "loss" in r])  # every start's steps
        v = np.asarray(o3d.io.read_triangle_mesh(str(path)).vertices)
        out[k] = (losses, v)
    return out


def test_short_stage1_run_same_loss_curve(runs):
    """Same loss at every step for k = 1e-3, 1, 1e3 (rel. 1e-3: the unit-frame cameras differ
    by float rounding only), all finite, and the run did change the loss."""
    ref, _ = runs[1.0]
    g = _cfg().grid  # each extra start is a whole run
    assert len(ref) == STEPS + len(g.init_candidates) * STEPS
    assert np.isfinite(ref).all()
    assert abs(ref[-1] - ref[0]) > 1e-3 * ref[0]
    for k, (losses, _) in runs.items():
        assert np.isfinite(losses).all(), k
        np.testing.assert_allclose(losses, ref, rtol=1e-3, err_msg=f"k={k}")


def test_mesh_in_the_input_frame_scales_back(runs, scenes):
    """Mesh bounding box (input frame) = k × the unscaled one (centre and extent), and the
    mesh lies where the unit-frame surface maps to (inside the scene's radius)."""
    _, vref = runs[1.0]
    lo0, hi0 = vref.min(0), vref.max(0)
    for k, (_, v) in runs.items():
        assert len(v) > 100
        lo, hi = v.min(0), v.max(0)
        np.testing.assert_allclose((hi - lo) / (hi0 - lo0), k, rtol=1e-4, err_msg=f"k={k}")
        np.testing.assert_allclose(0.5 * (lo + hi), k * 0.5 * (lo0 + hi0), rtol=1e-4,
                                   atol=1e-6 * k, err_msg=f"k={k}")
        sc = scenes[k]
        r = np.linalg.norm(v - sc.norm.center, axis=1) / sc.norm.scale
        assert r.max() < 1.05
