"""``voxnero material`` → ``voxnero relight``: a stage-2 export relit under its own recovered
env map reproduces the photos it was fitted to (end to end through both CLIs)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from tests.material.stage2_scene import ring_cameras, smooth_env
from voxnero.cli import main
from voxnero.io.color import linear_to_srgb


def _scene(root, n=4, size=32):
    """NeRF-synthetic scene of a sphere r = 0.5 rendered by our own relighter (gold-ish metal,
    r = 0.3) under a smooth env map; the mesh is written as mesh.ply."""
    import open3d as o3d

    from voxnero.asset.model import Asset, UniformMaterial
    from voxnero.relight.render import RelightConfig, Relighter
    from voxnero.render.envmap import EnvMap

    cams = ring_cameras(n, size, dist=4.0)
    env = smooth_env(16)
    mesh = o3d.geometry.TriangleMesh.create_sphere(0.5, 30)
    mesh.compute_vertex_normals()
    asset = Asset(torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32),
                  torch.as_tensor(np.asarray(mesh.triangles)),
                  torch.as_tensor(np.asarray(mesh.vertex_normals), dtype=torch.float32),
                  UniformMaterial((0.9, 0.7, 0.35), 1.0, 0.3))
    rel = Relighter(asset, EnvMap(env), RelightConfig(spp=16, bounces=1))
    (root / "train").mkdir(parents=True)
    frames = []
    for i in range(n):
        lin = rel.render(cams, i, torch.Generator().manual_seed(i))["rgb"]
        img = np.rint(np.asarray(linear_to_srgb(lin.clamp(0, 1))) * 255)
        Image.fromarray(img.astype(np.uint8)).save(root / "train" / f"r_{i}.png")
        c2w_gl = cams.c2w[i].numpy().astype(np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])
        frames.append({"file_path": f"./train/r_{i}", "transform_matrix": c2w_gl.tolist()})
    fov = 2 * math.atan(0.5 * size / float(cams.K[0, 0, 0]))
    (root / "transforms_train.json").write_text(json.dumps({"camera_angle_x": fov,
                                                            "frames": frames}))
    o3d.io.write_triangle_mesh(str(root / "mesh.ply"), mesh)


@pytest.mark.slow
def test_stage2_export_relit_under_its_env_reproduces_the_photos(tmp_path):
    torch.set_num_threads(1)
    scene = tmp_path / "scene"
    _scene(scene)
    mat = tmp_path / "mat"
    assert main(["material", "--scene", str(scene), "--out", str(mat), "--no-progress",
                 str(scene / "mesh.ply"), "iters=150", "batch=64", "texture_size=64",
                 "eval_views=0", "light.env_height=[16]", "threads=1"]) == 0
    out = tmp_path / "relit"
    assert main(["relight", str(mat), "--env", str(mat / "envmap.exr"), "--scene", str(scene),
                 "--split", "train", "--out", str(out), "--no-progress", "spp=4",
                 "bounces=1"]) == 0
    rep = json.loads((out / "relight.json").read_text())
    assert len(rep["views"]) == 4
    # the asset (frame, textures, env) is consistent with the photos it came from
    assert rep["mean_psnr"] > 22.0, rep
    assert (out / "r_0.png").is_file() and (out / "exr" / "r_0.exr").is_file()
