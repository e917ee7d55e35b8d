"""Integration tests of voxnero/commands/eval.py (``voxnero eval``) through the CLI."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from PIL import Image

from voxnero.cli import main

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data"
SG = DATA / "sphere_gold"
needs_data = pytest.mark.skipif(not (SG / "gt" / "mesh.ply").is_file(),
                                reason=f"dev scene sphere_gold not found under {DATA}")


@needs_data
def test_eval_gt_mesh_of_sphere_gold(tmp_path, capsys):
    out = tmp_path / "eval"
    rc = main(["eval", str(SG / "gt" / "mesh.ply"), "--scene", str(SG), "--out", str(out)])
    assert rc == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["chamfer"]["cd"] <= 0.002  # measured 0.00176
    assert m["chamfer"]["frame"] == "input" and m["n_views"] == 16
    # against its own depth at the pixel centres the truth scores 0; the protocol's floor is
    # what it scores against the stored (pixel-averaged) depth
    assert m["chamfer_exact"]["cd"] <= 1e-9
    assert m["chamfer_exact"]["truth_cd"] == pytest.approx(m["chamfer"]["cd"], rel=1e-6)
    assert m["normals"]["mean_deg"] < 0.5  # measured 0.066° (vertex normals from the PLY)
    assert "| chamfer.cd |" in (out / "metrics.md").read_text()
    img = Image.open(out / "normals_r_000.png")
    assert img.size[1] == 256
    assert yaml.safe_load((out / "config.yaml").read_text())["eval"]["voxel"] == 0.01
    assert "chamfer 0.0017" in capsys.readouterr().out


@needs_data
def test_eval_run_folder_finds_scene_in_config(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy(SG / "gt" / "mesh.ply", run / "mesh.ply")
    (run / "config.yaml").write_text(yaml.safe_dump({"shape": {}, "_meta": {"scene": str(SG)}}))
    out = tmp_path / "eval"
    # overrides right after the target: argparse does not collect positionals after --out
    assert main(["eval", str(run), "views=[0, 5]", "images=0", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["n_views"] == 2 and m["chamfer"]["cd"] < 0.003
    assert not list(out.glob("*.png"))


@needs_data
def test_mesh_in_the_wrong_frame_is_flagged(tmp_path, capsys):
    import open3d as o3d

    far = o3d.geometry.TriangleMesh.create_sphere(0.5)
    far.translate((50.0, 0.0, 0.0))  # e.g. a mesh written in some other frame
    path = tmp_path / "far.ply"
    o3d.io.write_triangle_mesh(str(path), far)
    out = tmp_path / "eval"
    assert main(["eval", str(path), "views=[0]", "images=0", "--scene", str(SG),
                 "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    assert m["chamfer"]["cd"] == "inf" and m["chamfer"]["n_pred"] == 0
    assert "input frame" in m["warning"] and "warning:" in capsys.readouterr().out


def test_errors_are_one_line_exit_2(tmp_path, capsys):
    empty = tmp_path / "run"
    empty.mkdir()
    assert main(["eval", str(empty), "--scene", str(SG), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "holds no mesh.ply" in err and "Traceback" not in err
    mesh = tmp_path / "m.ply"
    mesh.write_text("ply\n")
    assert main(["eval", str(mesh), "--out", str(tmp_path / "o")]) == 2
    assert "no scene to evaluate against" in capsys.readouterr().err
    assert main(["eval", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    assert "no such run folder or mesh file" in capsys.readouterr().err


@needs_data
def test_scene_without_ground_truth_is_a_data_error(tmp_path, capsys):
    scene = tmp_path / "scene"
    scene.mkdir()
    for name in ("transforms_train.json", "transforms_test.json", "train", "test"):
        (scene / name).symlink_to(SG / name)
    rc = main(["eval", str(SG / "gt" / "mesh.ply"), "--scene", str(scene),
               "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert rc == 2 and "no ground truth" in err and "test_mask/" in err


def _panels(png: Path) -> tuple:
    """Prediction and truth panels of a comparison PNG (``pred | gap | truth | ...``), in [0, 1]."""
    import numpy as np

    from voxnero.eval.report import GAP

    a = np.asarray(Image.open(png)).astype(np.float64) / 255
    w = a.shape[0]  # square test views
    return a[:, :w], a[:, w + GAP:2 * w + GAP]


def test_eval_of_a_stage2_run(tmp_path, capsys):
    """``voxnero material`` on a tiny synth sphere, then ``voxnero eval`` on its folder."""
    import math

    import numpy as np

    from voxnero.synth.config import SynthConfig
    from voxnero.synth.make import make_scene

    cfg = SynthConfig(resolution=32, n_train=6, n_test=3, spp=4)
    cfg.env.height = 32
    scene = make_scene("sphere", tmp_path / "scene", cfg, progress=False)
    run = tmp_path / "run"
    assert main(["material", str(scene / "gt" / "mesh.ply"), "iters=60", "batch=16",
                 "texture_size=64", "eval_views=0", "render.spp_cos=2", "render.spp_ggx=2",
                 "render.spp_env=2", "light.env_height=[16]", "threads=1", "bg_batch=1024",
                 "--scene", str(scene), "--out", str(run), "--no-progress"]) == 0
    capsys.readouterr()
    out = tmp_path / "eval"
    # the scene comes from the run's config.yaml; first test view only, one comparison each
    assert main(["eval", str(run), "material_views=1", "images=1", "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    # (1) geometry: the stage-1 mesh the run was fitted on (here the GT sphere's mesh)
    assert m["mesh"] == str(scene / "gt" / "mesh.ply") and m["run"] == str(run)
    assert m["chamfer"]["cd"] < 0.02 and m["normals"]["mean_deg"] < 3
    # (2) image / material metrics of the exported asset
    assert m["views"] == [0] and m["asset"] == str(run / "model.glb")
    # rendered with the light model stage 2 trained with, not re-decided per view
    trained = json.loads((run / "materials.json").read_text())["decisions"]["indirect_model"]
    assert m["indirect"] == trained
    for k in ("psnr", "psnr_object"):
        assert math.isfinite(m["novel_view"][k]) and m["novel_view"][k] > 15, k
    assert 0 < m["novel_view"]["ssim"] <= 1
    for k in ("metallic_mae", "roughness_mae"):
        assert 0 <= m["materials"][k] <= 1, k
    assert math.isfinite(m["materials"]["albedo_psnr"]) and m["materials"]["albedo_psnr"] > 15
    assert "images" not in m  # the stage-1 "not evaluated" note is gone
    md = (out / "metrics.md").read_text()
    assert "| novel_view.psnr |" in md and "| materials.metallic_mae |" in md
    # the comparison PNG is the same render (same seed) as the metric: its 8-bit panels give
    # the same whole-image PSNR up to quantisation
    pred, gt = _panels(out / "render_r_000.png")
    psnr_png = -10 * math.log10(float(np.mean((pred - gt) ** 2)))
    assert abs(psnr_png - m["novel_view"]["psnr"]) < 0.5
    assert (out / "normals_r_000.png").is_file() and not (out / "render_r_001.png").exists()
    assert "novel views PSNR" in capsys.readouterr().out
    # a relight split (the test views under a map, here the scene's own): rendered and scored
    # by default, skipped with material_relight=false, which leaves the other numbers alone
    import shutil

    shutil.copytree(scene / "test", scene / "test_relight_same")
    shutil.copy(scene / "transforms_test.json", scene / "transforms_test_relight_same.json")
    shutil.copy(scene / "gt" / "envmap.exr", scene / "gt" / "envmap_same.exr")
    with_relight, without = tmp_path / "eval_r", tmp_path / "eval_nr"
    assert main(["eval", str(run), "material_views=1", "images=0", "--out",
                 str(with_relight)]) == 0
    assert main(["eval", str(run), "material_views=1", "images=0", "material_relight=false",
                 "--out", str(without)]) == 0
    mr = json.loads((with_relight / "metrics.json").read_text())
    mn = json.loads((without / "metrics.json").read_text())
    assert math.isfinite(mr["relight"]["same"]["psnr"]) and mn["relight"] == {}
    assert mn["novel_view"] == mr["novel_view"] and mn["materials"] == mr["materials"]
    capsys.readouterr()
    # a bad setting is a one-line config error
    assert main(["eval", str(run), "material_views=0", "--out", str(out)]) == 2
    assert "material_views" in capsys.readouterr().err
