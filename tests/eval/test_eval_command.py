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
