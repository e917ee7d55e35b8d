"""Format detection, and THE convention test: the dev scenes' ground-truth meshes, seen through
our cameras and rays, must cover their evaluation masks (IoU >= 0.98 in every view)."""

from __future__ import annotations

import time

import numpy as np
import open3d as o3d
import pytest
import torch

from tests.fixtures.scenes import make_blender, make_colmap, make_nero
from voxnero.cameras.rays import image_rays, pixel_centers, pixel_rays
from voxnero.data.detect import available_splits, detect_format, load_scene
from voxnero.errors import DataError


def test_detects_each_format(tmp_path):
    make_blender(tmp_path / "b", n={"train": 2, "val": 1})
    make_nero(tmp_path / "n", n=2, with_depth=False)
    make_colmap(tmp_path / "c", n=2, binary=True)
    assert detect_format(tmp_path / "b") == "blender"
    assert detect_format(tmp_path / "n") == "nero"
    assert detect_format(tmp_path / "c") == "colmap"
    assert detect_format(tmp_path) is None
    assert load_scene(tmp_path / "b" / "transforms_train.json").format == "blender"  # a file
    assert load_scene(tmp_path / "n").format == "nero"
    assert load_scene(tmp_path / "c" / "sparse" / "0", images_dir=tmp_path / "c" / "images"
                      ).format == "colmap"
    assert available_splits(tmp_path / "b") == ["train", "val"]
    assert available_splits(tmp_path / "n") == ["train"]


def test_no_known_format_lists_what_it_looked_for(tmp_path):
    (tmp_path / "photo.png").write_bytes(b"")
    with pytest.raises(DataError, match="no known format") as e:
        load_scene(tmp_path)
    msg = str(e.value)
    assert "transforms_train.json" in msg and "camera.pkl" in msg and "sparse/0" in msg
    with pytest.raises(DataError, match="scene folder not found"):
        load_scene(tmp_path / "nothing")


# --------------------------------------------------------------------------------------------
# dev scenes (skipped only when ../shared/data is absent)
# --------------------------------------------------------------------------------------------

def silhouettes(mesh_path, split, norm) -> np.ndarray:
    """``(N, H, W)`` bool: rays through every pixel centre (ours) that hit the mesh, after
    mapping the world-frame mesh into the unit frame with the scene's normalisation."""
    mesh = o3d.io.read_triangle_mesh(str(mesh_path))
    v = norm.to_unit(np.asarray(mesh.vertices)).astype(np.float32)
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(v), o3d.core.Tensor(np.asarray(mesh.triangles, np.uint32)))
    n, h, w = split.n, split.height, split.width
    pix = pixel_centers(h, w).reshape(1, -1, 2).expand(n, -1, -1).reshape(-1, 2)
    cam = torch.arange(n).repeat_interleave(h * w)
    rays = torch.cat(pixel_rays(split.cameras, cam, pix), -1).reshape(n, h, w, 6).numpy()
    # any hit along the ray (tfar = inf) is the silhouette; test_occlusions is the cheap query
    return rc.test_occlusions(o3d.core.Tensor(rays)).numpy().astype(bool)


@pytest.mark.parametrize("name", ["sphere_gold", "torus_ceramic"])
def test_dev_mesh_projects_onto_masks(dev_data, name):
    t0 = time.perf_counter()
    sc = load_scene(dev_data / name, splits=("train", "test"), eval_extras=True)
    load_s = time.perf_counter() - t0
    assert sc.format == "blender" and sc.up.tolist() == [0, 0, 1]
    for split in ("train", "test"):
        sp = sc.split(split)
        assert sp.masks is not None
        hit = silhouettes(dev_data / name / "gt" / "mesh.ply", sp, sc.norm)
        gt = sp.masks.numpy() >= 0.5
        iou = (hit & gt).sum((1, 2)) / (hit | gt).sum((1, 2))
        worst = int(iou.argmin())
        assert iou.min() >= 0.98, f"{name}/{split}: view {sp.names[worst]} IoU {iou.min():.4f}"
    # 112 images + 112 masks + 16 EXR depth maps
    assert load_s < 15, f"loading took {load_s:.1f} s"


def test_dev_rays_match_readme_formula_after_normalisation(dev_data):
    """Unit-frame rays = README's Blender formula, with origins mapped by the normalisation."""
    import json

    sc = load_scene(dev_data / "torus_ceramic")
    meta = json.loads((dev_data / "torus_ceramic" / "transforms_train.json").read_text())
    f = 0.5 * meta["w"] / np.tan(0.5 * meta["camera_angle_x"])
    sp = sc.split("train")
    for k in (0, 50, 95):
        m = np.asarray(meta["frames"][k]["transform_matrix"])
        i, j = np.meshgrid(np.arange(256) + 0.5, np.arange(256) + 0.5, indexing="xy")
        d = np.stack([(i - 128) / f, -(j - 128) / f, -np.ones_like(i)], -1) @ m[:3, :3].T
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        o, dirs = image_rays(sp.cameras, k)
        np.testing.assert_allclose(dirs.numpy(), d, atol=1e-6)
        np.testing.assert_allclose(sc.norm.to_input(o[0, 0].double().numpy()), m[:3, 3],
                                   atol=1e-5)


def test_dev_depth_backprojects_onto_the_sphere(dev_data):
    """gt/test_depth is z-depth: back-projected fully covered pixels lie on the r = 0.8 sphere."""
    sc = load_scene(dev_data / "sphere_gold", splits=("test",), eval_extras=True)
    sp = sc.split("test")
    full = sp.masks.numpy() >= 1.0
    for k in range(0, sp.n, 5):
        o, d = image_rays(sp.cameras, k)
        cos = (d * sp.cameras.forward[k]).sum(-1)
        p = o + (sp.depth[k] / cos)[..., None] * d
        r = np.linalg.norm(sc.norm.to_input(p.double().numpy())[full[k]], axis=-1)
        # half-float depth (spacing 2^-9 near 4) and box-filtered pixels: ~2e-3; Euclidean
        # distance read as z-depth would be off by up to 0.04
        assert np.abs(r - 0.8).max() < 3e-3


def test_dev_train_images_load_fast(dev_data):
    t0 = time.perf_counter()
    sp = load_scene(dev_data / "sphere_gold").split("train")
    dt = time.perf_counter() - t0
    assert sp.images.shape == (96, 256, 256, 3) and sp.images.dtype == torch.float32
    assert 0 <= float(sp.images.min()) and float(sp.images.max()) <= 1
    assert dt < 10, f"{dt:.1f} s for 96 images"
