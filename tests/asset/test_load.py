"""Tests of voxnero/asset/load.py and the readers of asset/gltf.py, asset/obj.py, asset/gt.py:
exported glb / obj come back in the scene frame with their materials."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.asset.gltf import load_glb
from voxnero.asset.load import load_asset
from voxnero.asset.model import TextureMaterial, UniformMaterial, sample_texture
from voxnero.asset.obj import load_obj
from voxnero.errors import DataError

DEV = Path("/work/shared/data")


def _vertex_index(a, b):
    """For each row of a (N, 3), the index of the nearest row of b."""
    d = ((a[:, None, :] - b[None, :, :]) ** 2).sum(-1)
    return d.argmin(1), d.min(1)


def test_glb_positions_back_in_scene_frame(sphere_asset_files):
    glb, _, tm, _ = sphere_asset_files
    a = load_glb(glb)
    # the file stores (x, z, -y): loading must undo it exactly (not just any rotation)
    np.testing.assert_allclose(a.vertices.numpy(), tm.positions, atol=1e-6)
    np.testing.assert_allclose(a.normals.numpy(), tm.normals, atol=1e-5)
    np.testing.assert_array_equal(a.triangles.numpy(), tm.indices.astype(np.int64))
    np.testing.assert_allclose(a.up, [0, 0, 1])
    # the sphere is centred at (0.1, 0.2, 0.3) in the scene frame
    c, r = a.bounds()
    np.testing.assert_allclose(c, [0.1, 0.2, 0.3], atol=0.02)
    assert abs(r - 0.5) < 0.01


def test_glb_without_sidecar_stays_in_gltf_frame(sphere_asset_files, tmp_path):
    glb, _, tm, _ = sphere_asset_files
    p = tmp_path / "bare.glb"
    p.write_bytes(glb.read_bytes())
    a = load_glb(p)
    expect = tm.positions @ np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float).T
    np.testing.assert_allclose(a.vertices.numpy(), expect, atol=1e-6)
    np.testing.assert_allclose(a.up, [0, 1, 0])


@pytest.mark.parametrize("kind", ["glb", "obj"])
def test_materials_match_the_baked_vertex_values(sphere_asset_files, kind):
    glb, obj, tm, vals = sphere_asset_files
    a = load_glb(glb) if kind == "glb" else load_obj(obj)
    assert isinstance(a.material, TextureMaterial)
    alb, met, rough = a.vertex_material()
    import open3d as o3d

    m = o3d.geometry.TriangleMesh.create_sphere(0.5, 20).translate([0.1, 0.2, 0.3])
    src = np.asarray(m.vertices)
    idx, d2 = _vertex_index(a.vertices.numpy(), src)
    assert d2.max() < 1e-10
    # 8-bit textures (sRGB for albedo) baked from per-vertex values: a few 1/255 steps
    assert np.abs(alb.numpy() - vals["albedo"][idx]).mean() < 0.02
    assert np.abs(met.numpy()[:, 0] - vals["metallic"][idx]).mean() < 0.02
    assert np.abs(rough.numpy()[:, 0] - vals["roughness"][idx]).mean() < 0.02
    # and the ramps are not constant (the channels were not swapped / flattened)
    assert np.corrcoef(met.numpy()[:, 0], a.vertices.numpy()[:, 0])[0, 1] > 0.95
    assert np.corrcoef(rough.numpy()[:, 0], a.vertices.numpy()[:, 2])[0, 1] > 0.95


def test_obj_and_glb_agree(sphere_asset_files):
    glb, obj, _, _ = sphere_asset_files
    g, o = load_glb(glb), load_obj(obj)
    # vertices are split along atlas seams: match on position and texture coordinate
    ko = np.concatenate([o.vertices.numpy(), o.material.uvs.numpy()], 1)
    kg = np.concatenate([g.vertices.numpy(), g.material.uvs.numpy()], 1)
    idx, d2 = _vertex_index(ko, kg)
    assert d2.max() < 1e-10
    ga, gm, gr = g.vertex_material()
    oa, om, orr = o.vertex_material()
    # the same texels through both files (OBJ flips v on write, the loader flips it back);
    # each file holds its own 8-bit PNGs, so a texel may differ by a rounding step or two
    # (seen once: 0.0068 = 1.7/255 on one vertex of 2454); a flipped v would be off by far more
    for of, gf in ((oa, ga), (orr, gr)):
        diff = np.abs(of.numpy() - gf.numpy()[idx])
        assert (diff > 2e-3).mean() < 1e-3 and diff.max() < 2.5 / 255


@settings(max_examples=40, deadline=None)
@given(u=st.floats(0.0, 1.0), v=st.floats(0.0, 1.0))
def test_sample_texture_is_bilinear_on_texel_centres(u, v):
    # a texture linear in the texel index is reproduced exactly inside the centre grid
    S = 8
    j, i = np.meshgrid(np.arange(S), np.arange(S), indexing="ij")
    tex = torch.tensor(np.stack([i, j], -1), dtype=torch.float64)
    out = sample_texture(tex, torch.tensor([[u, v]], dtype=torch.float64))[0]
    ex = np.clip(u * S - 0.5, 0, S - 1)
    ey = np.clip(v * S - 0.5, 0, S - 1)
    assert abs(float(out[0]) - ex) < 1e-9 and abs(float(out[1]) - ey) < 1e-9


@pytest.mark.skipif(not (DEV / "torus_ceramic").is_dir(), reason="dev scenes not present")
def test_ground_truth_asset():
    a = load_asset(f"gt:{DEV / 'torus_ceramic'}")
    doc = json.loads((DEV / "torus_ceramic" / "gt" / "material.json").read_text())["material"]
    assert isinstance(a.material, UniformMaterial)
    alb, met, rough = a.material_at(torch.tensor([0, 5]), torch.full((2, 3), 1 / 3))
    np.testing.assert_allclose(alb.numpy(), [doc["base_color"]] * 2, atol=1e-7)
    assert float(met[0, 0]) == doc["metallic"] and float(rough[1, 0]) == doc["roughness"]
    assert a.scene == DEV / "torus_ceramic"
    # rendered by Mitsuba's principled BSDF (material.json "bsdf"): renders use its diffuse lobe
    assert a.diffuse == "principled"
    # torus R 0.62 + r 0.26: bounding radius 0.88 about the origin
    c, r = a.bounds()
    assert np.abs(c).max() < 0.01 and abs(r - 0.88) < 0.01


def test_missing_things_are_data_errors(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        load_asset(tmp_path / "nope.glb")
    with pytest.raises(DataError, match="no asset here"):
        load_asset(tmp_path)
    (tmp_path / "x.stl").write_text("solid")
    with pytest.raises(DataError, match="unsupported"):
        load_asset(tmp_path / "x.stl")
    with pytest.raises(DataError, match="ground-truth"):
        load_asset(f"gt:{tmp_path}")


def _reconstruct_folder(root: Path, glb: Path, obj: Path, stage1: bool = True) -> Path:
    """A ``voxnero reconstruct`` output folder: ``material/`` (model.glb + sidecar, model.obj)
    and ``shape/mesh.ply``."""
    import shutil

    mat = root / "material"
    mat.mkdir(parents=True)
    for f in (glb, glb.with_suffix(".glb.json"), obj, *obj.parent.glob("*.mtl"),
              *obj.parent.glob("*.png")):
        shutil.copy(f, mat / f.name)
    if stage1:
        (root / "shape").mkdir()
        (root / "shape" / "mesh.ply").write_text("ply\n")  # only its path is used here
    return root


def test_reconstruct_folder_loads_its_material_run(sphere_asset_files, tmp_path):
    glb, obj, tm, _ = sphere_asset_files
    run = _reconstruct_folder(tmp_path / "recon", glb, obj)
    a = load_asset(run)
    ref = load_glb(glb)
    assert a.source == str(run / "material" / "model.glb")
    np.testing.assert_array_equal(a.vertices.numpy(), ref.vertices.numpy())
    np.testing.assert_array_equal(a.triangles.numpy(), ref.triangles.numpy())
    assert a.stage1_mesh == run / "shape" / "mesh.ply"
    # the material folder itself still loads, without the sibling stage-1 mesh
    assert load_asset(run / "material").stage1_mesh is None


def test_reconstruct_folder_before_stage2_is_a_data_error(tmp_path):
    (tmp_path / "material").mkdir()
    (tmp_path / "shape").mkdir()
    with pytest.raises(DataError, match="material/model.glb") as e:
        load_asset(tmp_path)
    assert "reconstruct" in str(e.value)
