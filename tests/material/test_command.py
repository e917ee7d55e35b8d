"""``voxnero material`` / ``voxnero reconstruct`` through the CLI on a tiny code-built scene."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from tests.material.stage2_scene import ring_cameras, smooth_env, sphere_geometry
from voxnero.cli import main
from voxnero.commands.material import locate
from voxnero.commands.reconstruct import split_overrides
from voxnero.errors import ConfigError, DataError
from voxnero.io.color import linear_to_srgb
from voxnero.io.exr import read_envmap
from voxnero.material.surface import build_cache
from voxnero.render.latlong import envmap_lookup


def _write_scene(root, n=4, size=32):
    """A NeRF-synthetic scene (transforms_train.json + PNGs) of a sphere r = 0.5 in front of a
    known env map; the mesh is written as mesh.ply. Object pixels are a flat colour (only the
    plumbing is tested here)."""
    import open3d as o3d

    cams = ring_cameras(n, size, dist=4.0)
    env = smooth_env(16)
    geom = sphere_geometry(0.5, 30)
    (root / "train").mkdir(parents=True)
    frames = []
    from voxnero.cameras.rays import image_rays

    for i in range(n):
        o, d = image_rays(cams, i)
        _, tri, _ = geom.cast(o.reshape(-1, 3), d.reshape(-1, 3))
        lin = envmap_lookup(env, d.reshape(-1, 3))
        lin[tri >= 0] = torch.tensor([0.6, 0.4, 0.2])
        img = np.rint(np.asarray(linear_to_srgb(lin.clamp(0, 1))).reshape(size, size, 3) * 255)
        Image.fromarray(img.astype(np.uint8)).save(root / "train" / f"r_{i}.png")
        c2w_gl = cams.c2w[i].numpy().astype(np.float64) @ np.diag([1.0, -1.0, -1.0, 1.0])
        frames.append({"file_path": f"./train/r_{i}", "transform_matrix": c2w_gl.tolist()})
    fov = 2 * math.atan(0.5 * size / float(cams.K[0, 0, 0]))
    (root / "transforms_train.json").write_text(json.dumps({"camera_angle_x": fov,
                                                            "frames": frames}))
    mesh = o3d.geometry.TriangleMesh.create_sphere(0.5, 30)
    mesh.compute_vertex_normals()
    o3d.io.write_triangle_mesh(str(root / "mesh.ply"), mesh)
    return env, cams, geom


def test_material_command_writes_the_asset(tmp_path):
    scene = tmp_path / "scene"
    env, cams, geom = _write_scene(scene)
    out = tmp_path / "out"
    argv = ["material", "--scene", str(scene), "--out", str(out), "--no-progress",
            str(scene / "mesh.ply"), "iters=120", "batch=16", "texture_size=64",
            "eval_views=0", "render.spp_cos=2", "render.spp_ggx=2", "render.spp_env=2",
            "light.env_height=[16]", "lr_env=0.1", "threads=1", "bg_batch=2048"]
    rc = main(argv)
    assert rc == 0
    for name in ("model.glb", "model.glb.json", "model.obj", "model.mtl", "model_albedo.png",
                 "envmap.exr", "envmap.json", "materials.json", "config.yaml", "checkpoint.pt"):
        assert (out / name).is_file(), name
    doc = json.loads((out / "materials.json").read_text())
    assert set(doc) >= {"albedo_linear", "metallic", "roughness_perceptual", "envmap"}
    # the exported env map, rendered as the background of the training views, matches them:
    # it started from the background pixels themselves (nearest cell) and was fitted to them
    back = torch.from_numpy(read_envmap(out / "envmap.exr"))
    assert back.shape == (16, 32, 3)
    assert doc["metrics"]["background_psnr_train"] > 30
    # the env map is in the input frame: same mapping as the env that made the images
    cache = build_cache(geom, torch.zeros(4, 32, 32, 3), cams, max_pixels=0)
    err = (envmap_lookup(back, cache.bg_dirs) - envmap_lookup(env, cache.bg_dirs)).abs()
    assert float(err.median()) < 0.05
    # a second run resumes from the checkpoint (no further steps) and rewrites the outputs;
    # the export settings may change (texture_size), those that shaped the model may not
    rc = main(argv + ["texture_size=32"])
    assert rc == 0
    assert (out / "model_albedo.png").is_file()


def test_locate_and_errors(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    with pytest.raises(DataError):
        locate(run, None)
    (run / "mesh.ply").write_text("x")
    with pytest.raises(ConfigError):
        locate(run, None)
    (run / "config.yaml").write_text("shape: {}\n_meta: {scene: /data/s}\n")
    assert locate(run, None) == (run / "mesh.ply", __import__("pathlib").Path("/data/s"))
    assert locate(run / "mesh.ply", "/x")[1].name == "x"
    with pytest.raises(DataError):
        locate(tmp_path / "nope.ply", "/x")


def test_reconstruct_splits_overrides_by_stage():
    assert split_overrides(["shape.iters=3", "material.iters=4"]) == (["shape.iters=3"],
                                                                       ["material.iters=4"])
    with pytest.raises(ConfigError):
        split_overrides(["iters=3"])


def test_material_divides_the_photos_by_stage_one_gains(tmp_path, capsys):
    """Photo 0 taken at half the exposure: with stage 1's ``exposure.json`` beside the mesh the
    command divides it out (and says so), and the env map learned where only photo 0 sees the
    background is the true one; without the file it is about half as bright there."""
    from voxnero.fields.exposure import write_gains
    from voxnero.io.color import srgb_to_linear

    scene = tmp_path / "scene"
    env, cams, geom = _write_scene(scene)
    p = scene / "train" / "r_0.png"
    lin = srgb_to_linear(torch.from_numpy(np.asarray(Image.open(p)) / 255.0).float())
    dark = np.rint(np.asarray(linear_to_srgb(0.5 * lin)) * 255).astype(np.uint8)
    Image.fromarray(dark).save(p)
    over = ["iters=120", "batch=16", "texture_size=64", "eval_views=0", "render.spp_cos=2",
            "render.spp_ggx=2", "render.spp_env=2", "light.env_height=[16]", "lr_env=0.1",
            "threads=1", "bg_batch=2048"]
    dirs = build_cache(geom, torch.zeros(1, 32, 32, 3), cams[[0]], max_pixels=0).bg_dirs
    ratio = {}
    for name in ("without", "with"):
        run = tmp_path / name
        run.mkdir()
        (run / "mesh.ply").write_bytes((scene / "mesh.ply").read_bytes())
        if name == "with":
            write_gains(run / "exposure.json", [f"r_{i}" for i in range(4)],
                        torch.tensor([[0.5] * 3] + [[1.0] * 3] * 3))
        assert main(["material", "--scene", str(scene), "--out", str(run / "out"),
                     "--no-progress", str(run / "mesh.ply"), *over]) == 0
        back = torch.from_numpy(read_envmap(run / "out" / "envmap.exr"))
        ratio[name] = float((envmap_lookup(back, dirs).mean(-1)
                             / envmap_lookup(env, dirs).mean(-1)).median())
    assert "divided by stage 1's per-photo gains" in capsys.readouterr().out
    assert abs(ratio["with"] - 1.0) < 0.1 and ratio["without"] < 0.8, ratio
