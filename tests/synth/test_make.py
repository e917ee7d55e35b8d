"""Tests of voxnero/synth/make.py (+ writer.py, the `voxnero synth` command): written scenes load
with the project's loader and their ground truth agrees with the images and the analytic shapes.
"""

from __future__ import annotations

import json
import math

import numpy as np
import open3d as o3d
import pytest
import torch
import yaml
from PIL import Image

from voxnero.cameras.rays import image_rays
from voxnero.cli import main
from voxnero.config import from_dict
from voxnero.data.detect import load_scene
from voxnero.io.color import linear_to_srgb
from voxnero.io.exr import read_exr
from voxnero.synth import make_scene
from voxnero.synth.config import EnvConfig, SynthConfig
from voxnero.synth.shapes import Torus


def _cfg(**kw) -> SynthConfig:
    base = dict(resolution=32, n_train=3, n_test=2, spp=4, max_depth=1,
                env=EnvConfig(height=32))
    base.update(kw)
    return SynthConfig(**base)


@pytest.fixture(scope="module")
def sphere128(tmp_path_factory):
    """A 128² sphere scene (4 train + 2 test views) for the mask/mesh/GT checks."""
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("sphere128")
    return make_scene("sphere", out, _cfg(resolution=128, n_train=4, n_test=2, spp=9),
                      progress=False)


@pytest.fixture(scope="module")
def torus64(tmp_path_factory):
    torch.set_num_threads(1)
    out = tmp_path_factory.mktemp("torus64")
    return make_scene("torus", out, _cfg(resolution=128, n_train=2, n_test=3, spp=4),
                      progress=False)


def test_layout_and_formats_match_the_dev_scenes(sphere128):
    root = sphere128
    doc = json.loads((root / "transforms_train.json").read_text())
    assert {"camera_angle_x", "w", "h", "fl_x", "fl_y", "cx", "cy", "frames"} <= set(doc)
    assert doc["camera_angle_x"] == pytest.approx(math.radians(40.0))
    assert doc["fl_x"] == pytest.approx(0.5 * 128 / math.tan(math.radians(20)))
    assert (doc["cx"], doc["cy"], doc["w"], doc["h"]) == (64.0, 64.0, 128, 128)
    assert [f["file_path"] for f in doc["frames"]] == [f"./train/r_{i:03d}" for i in range(4)]
    for f in doc["frames"]:  # OpenGL c2w: camera at distance 4 looking down its -Z at 0
        m = np.array(f["transform_matrix"])
        assert np.linalg.norm(m[:3, 3]) == pytest.approx(4.0)
        assert np.allclose(-m[:3, 2], -m[:3, 3] / 4.0)
        assert m[2, 1] > 0  # image up has a positive world-Z component (no roll, up +Z)
    for rel in ["train/r_003.png", "train_mask/r_000.png", "test/r_001.png", "test_mask/r_001.png",
                "test_exr/r_000.exr", "gt/mesh.ply", "gt/material.json", "gt/envmap.exr",
                "gt/test_normal/r_000.exr", "gt/test_depth/r_001.exr", "gt/test_albedo/r_000.exr",
                "gt/test_metallic/r_000.exr", "gt/test_roughness/r_000.exr", "scene_info.json",
                "config.yaml", "transforms_test.json"]:
        assert (root / rel).is_file(), rel
    with Image.open(root / "train/r_000.png") as im:
        assert im.mode == "RGB" and im.size == (128, 128)
    with Image.open(root / "train_mask/r_000.png") as im:
        assert im.mode == "L"
    # PNG = round(255 · sRGB(clip(L))) of the linear EXR (half float: allow one level)
    png = np.asarray(Image.open(root / "test/r_000.png"), dtype=np.int32)
    exr = read_exr(root / "test_exr/r_000.exr")
    ref = np.rint(255 * linear_to_srgb(np.clip(exr, 0, 1))).astype(np.int32)
    assert np.abs(png - ref).max() <= 1 and (png == ref).mean() > 0.97
    info = json.loads((root / "scene_info.json").read_text())
    assert info["n_train"] == 4 and info["size_bytes"] > 0 and info["timings_s"]["total"] > 0
    cfg = from_dict(SynthConfig, yaml.safe_load((root / "config.yaml").read_text())["synth"])
    assert cfg.resolution == 128 and cfg.spp == 9  # the resolved config reproduces the scene


@pytest.mark.parametrize("shape", ["sphere", "torus", "two_spheres"])
def test_loads_and_gt_mesh_projects_onto_masks(shape, sphere128, tmp_path):
    """Measured min IoU over all views at 128²: sphere 0.997, torus 0.994, two spheres 0.992
    (at 64², tiny preset: 0.996, 0.982, 0.980)."""
    root = sphere128
    if shape != "sphere":  # a smaller scene: 2 train + 1 test views
        root = make_scene(shape, tmp_path / shape, _cfg(resolution=128, n_train=2, n_test=1,
                                                        spp=4), progress=False)
    n_views = {"train": 4, "test": 2} if shape == "sphere" else {"train": 2, "test": 1}
    scene = load_scene(root, splits=("train", "test"), eval_extras=True)
    mesh = o3d.io.read_triangle_mesh(str(root / "gt" / "mesh.ply"))
    v = scene.norm.to_unit(np.asarray(mesh.vertices))
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.core.Tensor(v.astype(np.float32)),
                     o3d.core.Tensor(np.asarray(mesh.triangles).astype(np.uint32)))
    for name in ("train", "test"):
        split = scene.split(name)
        assert split.n == n_views[name] and split.masks is not None
        for i in range(split.n):
            o, d = image_rays(split.cameras, i)
            rays = torch.cat([o, d], -1).reshape(-1, 6).numpy().astype(np.float32)
            sil = np.isfinite(rs.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy())
            sil = sil.reshape(128, 128)
            mask = split.masks[i].numpy() > 0.5
            iou = (sil & mask).sum() / (sil | mask).sum()
            assert iou >= 0.98, (name, i, iou)


def test_gt_maps_agree_with_the_analytic_sphere(sphere128):
    scene = load_scene(sphere128, splits=("test",), eval_extras=True)
    split = scene.split("test")
    mat = json.loads((sphere128 / "gt" / "material.json").read_text())
    r, c = mat["geometry"]["radius"], np.array(mat["geometry"]["center"])
    for i in range(split.n):
        full = split.masks[i].numpy() >= 1.0
        empty = split.masks[i].numpy() == 0.0
        depth = read_exr(sphere128 / "gt/test_depth" / f"r_{i:03d}.exr")[..., 0]
        normal = read_exr(sphere128 / "gt/test_normal" / f"r_{i:03d}.exr")
        c2w = np.array(json.loads((sphere128 / "transforms_test.json").read_text())
                       ["frames"][i]["transform_matrix"])
        f = 0.5 * 128 / math.tan(math.radians(20))
        jj, ii = np.mgrid[0:128, 0:128] + 0.5
        d_cam = np.stack([(ii - 64) / f, -(jj - 64) / f, -np.ones_like(ii)], -1)  # README formula
        p = c2w[:3, 3] + depth[..., None] * (d_cam @ c2w[:3, :3].T)  # z-depth: d_cam.z = -1
        p = p[full]
        nrm = (p - c) / np.linalg.norm(p - c, axis=-1, keepdims=True)
        facing = (nrm * (c2w[:3, 3] - p)).sum(-1) / np.linalg.norm(c2w[:3, 3] - p, axis=-1) > 0.3
        assert np.abs(np.linalg.norm(p - c, axis=-1) - r)[facing].max() < 2e-3  # half-float depth
        cos = (normal[full] * nrm).sum(-1)[facing]
        ang = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        assert np.median(ang) < 0.3 and ang.max() < 3.0  # pixel-averaged normals, half float
        albedo = read_exr(sphere128 / "gt/test_albedo" / f"r_{i:03d}.exr")
        rough = read_exr(sphere128 / "gt/test_roughness" / f"r_{i:03d}.exr")[..., 0]
        metal = read_exr(sphere128 / "gt/test_metallic" / f"r_{i:03d}.exr")[..., 0]
        m = mat["material"]
        assert np.allclose(albedo[full], m["base_color"], atol=1e-3)
        assert np.allclose(rough[full], m["roughness"], atol=1e-3)
        assert np.allclose(metal[full], m["metallic"], atol=1e-3)
        assert (depth[empty] == 0).all() and (albedo[empty] == 0).all()


def test_torus_gt_depth_lies_on_the_torus(torus64):
    doc = json.loads((torus64 / "transforms_test.json").read_text())
    geo = json.loads((torus64 / "gt" / "material.json").read_text())["geometry"]
    torus = Torus(geo["major_radius"], geo["minor_radius"], geo["tilt_deg"])
    f = doc["fl_x"]
    n_full = 0
    for i, fr in enumerate(doc["frames"]):
        c2w = np.array(fr["transform_matrix"])
        mask = np.asarray(Image.open(torus64 / "test_mask" / f"r_{i:03d}.png"))
        depth = read_exr(torus64 / "gt/test_depth" / f"r_{i:03d}.exr")[..., 0]
        normal = read_exr(torus64 / "gt/test_normal" / f"r_{i:03d}.exr")
        jj, ii = np.mgrid[0:128, 0:128] + 0.5
        d_cam = np.stack([(ii - 64) / f, -(jj - 64) / f, -np.ones_like(ii)], -1)
        p = c2w[:3, 3] + depth[..., None] * (d_cam @ c2w[:3, :3].T)
        full = mask == 255
        pts = torch.as_tensor(p[full])
        n_ref = torus.normal(pts).numpy()
        facing = (n_ref * (c2w[:3, 3] - p[full])).sum(-1) > 0.3 * np.linalg.norm(
            c2w[:3, 3] - p[full], axis=-1)
        sd = torus.sdf(pts).abs().numpy()[facing]
        # pixel-averaged depth (a pixel straddling the tube and the tube behind it averages two
        # depths, as in the dev scenes), half float
        assert np.median(sd) < 1e-3 and np.percentile(sd, 95) < 5e-3
        cos = (normal[full] * n_ref).sum(-1)[facing]
        assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) < 2.0
        n_full += int(facing.sum())
    assert n_full > 300


def test_same_config_same_scene_and_seed_changes_noise(tmp_path):
    a = make_scene("two_spheres", tmp_path / "a", _cfg(n_test=0, n_train=1), progress=False)
    b = make_scene("two_spheres", tmp_path / "b", _cfg(n_test=0, n_train=1), progress=False)
    c = make_scene("two_spheres", tmp_path / "c", _cfg(n_test=0, n_train=1, seed=5),
                   progress=False)
    img = {k: np.asarray(Image.open(p / "train/r_000.png")) for k, p in zip("abc", (a, b, c),
                                                                               strict=True)}
    assert (img["a"] == img["b"]).all()
    assert (img["a"] != img["c"]).any()


def test_cli_writes_scene_and_resolved_config(tmp_path, capsys):
    out = tmp_path / "s"
    rc = main(["synth", "torus", "--preset", "tiny", "--out", str(out), "resolution=16",
               "n_train=2", "n_test=1", "spp=1", "torus.tilt_deg=45", "env.source=constant"])
    assert rc == 0
    cfg = yaml.safe_load((out / "config.yaml").read_text())
    assert cfg["synth"]["resolution"] == 16 and cfg["synth"]["torus"]["tilt_deg"] == 45.0
    assert cfg["synth"]["max_depth"] == 3  # from the tiny preset
    assert json.loads((out / "gt/material.json").read_text())["geometry"]["tilt_deg"] == 45.0
    assert len(list((out / "train").glob("*.png"))) == 2


@pytest.mark.parametrize("argv, msg", [
    (["synth", "cube"], "unknown synthetic shape"),
    (["synth", "sphere", "sphere.radius=2"], "> 0.9"),
    (["synth", "sphere", "sphere.material.roughness=3"], "roughness"),
    (["synth", "sphere", "spp=0"], "spp"),
    (["synth", "sphere", "env.source=/nonexistent.png"], "env.source"),
    (["synth", "sphere", "colour=red"], "unknown config key"),
])
def test_cli_user_errors_exit_2_with_a_message(tmp_path, capsys, argv, msg):
    rc = main(argv + ["--out", str(tmp_path / "x")])
    assert rc == 2
    err = capsys.readouterr().err
    assert msg in err and "Traceback" not in err


def test_project_evaluator_scores_the_gt_mesh_near_zero(torus64, tmp_path):
    """`voxnero eval` (NeRO Chamfer protocol on gt/test_depth) on our own GT mesh: measured
    Chamfer 0.0017 and normal error 0.37° at 128² (the dev scenes give 0.0018)."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "mesh.ply").write_bytes((torus64 / "gt" / "mesh.ply").read_bytes())
    assert main(["eval", str(run), "--scene", str(torus64), "--out", str(tmp_path / "ev")]) == 0
    metrics = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert metrics["chamfer"]["cd"] < 0.0025
    assert metrics["normals"]["mean_deg"] < 1.0
