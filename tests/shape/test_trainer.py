"""End-to-end tests of voxnero/shape/trainer.py on a tiny analytic sphere scene.

The scene is rendered here, independently of the model: a sphere of radius 0.5 (unit frame) with
a smooth diffuse shading in front of a textured distant environment, 64² pixels, 24 views on a
Fibonacci lattice. The reconstructed mesh is compared with the analytic sphere (radius, Chamfer),
and an interrupted run must resume from its checkpoint.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from voxnero.cameras.cameras import Cameras
from voxnero.cameras.rays import image_rays
from voxnero.config import from_dict
from voxnero.data.scene import Normalisation
from voxnero.eval.chamfer import chamfer_points
from voxnero.shape.config import ShapeConfig
from voxnero.shape.trainer import CKPT, ShapeTrainer

RADIUS = 0.5


def _env(d: torch.Tensor) -> torch.Tensor:
    """A smooth, textured distant environment (linear radiance) for unit directions d."""
    x, y, z = d.unbind(-1)
    r = 0.35 + 0.25 * torch.sin(3 * x + 1) * torch.cos(2 * y) + 0.2 * z
    g = 0.30 + 0.20 * torch.cos(4 * y - z) + 0.15 * x
    b = 0.40 + 0.25 * torch.sin(5 * z + 2 * x)
    return torch.stack([r, g, b], -1).clamp(0.02, 1.0)


def _cameras(n: int, size: int) -> Cameras:
    k = torch.arange(n, dtype=torch.float64) + 0.5
    zc = 1 - 2 * k / n * 0.8 - 0.1
    phi = k * math.pi * (3 - math.sqrt(5))
    rr = torch.sqrt(1 - zc * zc)
    eyes = 3.0 * torch.stack([rr * torch.cos(phi), rr * torch.sin(phi), zc], -1)
    c2w = torch.zeros(n, 4, 4, dtype=torch.float64)
    for i, e in enumerate(eyes):
        fwd = -e / e.norm()
        up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        right = torch.linalg.cross(fwd, up)
        right = right / right.norm()
        down = torch.linalg.cross(fwd, right)
        c2w[i, :3, 0], c2w[i, :3, 1], c2w[i, :3, 2], c2w[i, :3, 3] = right, down, fwd, e
        c2w[i, 3, 3] = 1
    f = 0.5 * size / math.tan(math.radians(20))
    K = torch.tensor([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]]).expand(n, 3, 3)
    return Cameras(K.float().clone(), c2w.float(), size, size)


def _scene(n: int = 24, size: int = 64) -> SimpleNamespace:
    cams = _cameras(n, size)
    imgs = []
    for i in range(n):
        o, d = image_rays(cams, i)
        b = (o * d).sum(-1)
        disc = b * b - ((o * o).sum(-1) - RADIUS**2)
        t = -b - torch.sqrt(disc.clamp(min=0))
        p = o + t[..., None] * d
        nrm = p / RADIUS
        surf = torch.tensor([0.7, 0.35, 0.2]) * (0.35 + 0.3 * (nrm[..., 2:] + 1))
        imgs.append(torch.where((disc > 0)[..., None], surf, _env(d)))
    split = SimpleNamespace(images=torch.stack(imgs).float(), cameras=cams, depth=None,
                            masks=None)
    return SimpleNamespace(split=lambda name: split, splits={"train": split},
                           norm=Normalisation(np.zeros(3), 1.0), background="unknown", meta={})


def _cfg(iters: int) -> ShapeConfig:
    return from_dict(ShapeConfig, {
        "iters": iters, "eval_every_s": 0, "preview_every": 0, "mesh_res": 96,
        "grid": {"res": [32, 48], "upsample_at": [0.4], "feat_res": 16},
        "sampling": {"rays": 1024, "coarse": 24, "fine": 12, "coarse_keep": 12},
        "neus": {"s_start": 20, "s_end": 150, "ramp": 0.7},
        "light": {"env_height": 32, "occlusion": "off", "metallic": "off"},
        "optim": {"lr_sdf": 4e-3},
    })


def _mesh_points(path) -> np.ndarray:
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(path))
    assert len(mesh.triangles) > 100
    o3d.utility.random.seed(0)
    return np.asarray(mesh.sample_points_uniformly(number_of_points=20000).points)


@pytest.fixture(scope="module")
def scene():
    return _scene()


def test_reconstructs_sphere_radius_and_chamfer(scene, tmp_path):
    torch.manual_seed(0)
    tr = ShapeTrainer(_cfg(400), scene, tmp_path, progress=False, log=lambda s: None)
    path = tr.run()
    pts = _mesh_points(path)
    r = np.linalg.norm(pts, axis=1)
    # a 48³ grid over [-1.05, 1.05]³ has 0.045 voxels; 64 px views: 1 px ≈ 0.017 at the object
    assert abs(np.median(r) - RADIUS) < 0.02, np.median(r)
    g = np.random.default_rng(0).normal(size=(20000, 3))
    gt = RADIUS * g / np.linalg.norm(g, axis=1, keepdims=True)
    cd = chamfer_points(pts, gt, voxel=0.01)["cd"]
    assert cd < 0.02, cd
    assert (tmp_path / "log.jsonl").is_file() and (tmp_path / "config.yaml").exists() is False


def test_interrupt_and_resume(scene, tmp_path):
    cfg = _cfg(40)
    tr = ShapeTrainer(cfg, scene, tmp_path, progress=False, log=lambda s: None)
    calls = {"n": 0}
    orig = tr.train_step

    def flaky():
        calls["n"] += 1
        if calls["n"] == 15:
            raise KeyboardInterrupt
        return orig()

    tr.train_step = flaky
    with pytest.raises(KeyboardInterrupt):
        tr.run()
    assert (tmp_path / CKPT).is_file()
    ck = torch.load(tmp_path / CKPT, weights_only=False)
    assert ck["step"] == 14
    saved_grid = ck["model"]["sdf.grid"].clone()
    tr2 = ShapeTrainer(cfg, scene, tmp_path, progress=False, log=lambda s: None)
    assert tr2.load_checkpoint()
    assert tr2.step == 14
    assert torch.equal(tr2.model.sdf.grid.data, saved_grid)
    # the resumed run continues to the end and writes the mesh
    tr3 = ShapeTrainer(cfg, scene, tmp_path, progress=False, log=lambda s: None)
    tr3.run()
    assert tr3.step == 40 and (tmp_path / "mesh.ply").is_file()
    steps = [line for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert len(steps) > 0
