"""Bad input through the CLI: every case is a DataError that names the file and the fix, printed
by ``voxnero info`` in one or two lines on stderr without a traceback, exit code 2."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from tests.fixtures.scenes import edit_json, make_blender, make_colmap, make_nero
from voxnero import cli
from voxnero.io.exr import write_exr


def mixed_sizes(root: Path) -> str:
    make_blender(root, n={"train": 3}, ngp_keys=False)
    Image.fromarray(np.zeros((10, 20, 3), np.uint8)).save(root / "train" / "r_1.png")
    return "r_1.png"


def mixed_sizes_with_wh(root: Path) -> str:
    make_blender(root, n={"train": 3}, ngp_keys=True)
    Image.fromarray(np.zeros((10, 20, 3), np.uint8)).save(root / "train" / "r_2.png")
    return "r_2.png"


def empty_split(root: Path) -> str:
    make_blender(root, n={"train": 2, "test": 1})
    edit_json(root / "transforms_test.json", lambda m: m.update(frames=[]))
    return "transforms_test.json"


def missing_image(root: Path) -> str:
    make_blender(root, n={"train": 3})
    (root / "train" / "r_1.png").unlink()
    return "transforms_train.json"


def unreadable_image(root: Path) -> str:
    make_blender(root, n={"train": 3})
    (root / "train" / "r_2.png").write_bytes(b"\x89PNG\r\n\x1a\n but then garbage")
    return "r_2.png"


def pose_wrong_shape(root: Path) -> str:
    make_blender(root, n={"train": 3})
    edit_json(root / "transforms_train.json",
               lambda m: m["frames"][1].update(transform_matrix=np.eye(3).tolist()))
    return "transforms_train.json"


def pose_non_finite(root: Path) -> str:
    make_blender(root, n={"train": 3})

    def f(m):
        m["frames"][2]["transform_matrix"][0][3] = float("nan")
    edit_json(root / "transforms_train.json", f)
    return "transforms_train.json"


def nero_pose_wrong_shape(root: Path) -> str:
    import pickle

    make_nero(root, n=3, with_depth=False)
    with open(root / "1-camera.pkl", "wb") as fh:
        pickle.dump([np.eye(4)[:2], np.eye(3) * 40], fh)
    return "1-camera.pkl"


def exr_nan(root: Path) -> str:
    make_blender(root, n={"train": 2})
    for i in range(2):
        d = np.full((32, 40), 3.0, np.float32)
        if i == 1:
            d[4, 5] = np.nan
        write_exr(root / "gt" / "train_depth" / f"r_{i}.exr", d)
    return "r_1.exr"


def unknown_camera_model(root: Path) -> str:
    make_colmap(root, n=2)
    p = root / "sparse" / "0" / "cameras.txt"
    p.write_text(p.read_text().replace(" PINHOLE ", " WEIRD_MODEL "))
    return "cameras.txt"


def unsupported_camera_model(root: Path) -> str:
    from voxnero.data.colmap import read_model, write_model

    make_colmap(root, n=2, binary=True)
    model = read_model(root / "sparse" / "0")
    cam = model.cameras[1]
    cam.model, cam.params = "OPENCV_FISHEYE", np.array([41, 43, 19.2, 14.7, 0.1, 0, 0, 0.0])
    write_model(model, root / "sparse" / "0", binary=True)
    return "cameras.bin"


def no_known_format(root: Path) -> str:
    root.mkdir(parents=True)
    (root / "notes.txt").write_text("hello")
    return str(root.name)


def missing_folder(root: Path) -> str:
    return "does_not_exist"


CASES = {
    "mixed_sizes": (mixed_sizes, ["mixed image sizes", "20x10"]),
    "mixed_sizes_with_wh": (mixed_sizes_with_wh, ["mixed image sizes", "expects 40x32"]),
    "empty_split": (empty_split, ["'test' is empty", "no frames"]),
    "missing_image": (missing_image, ["image file not found", "r_1"]),
    "unreadable_image": (unreadable_image, ["cannot read image"]),
    "pose_wrong_shape": (pose_wrong_shape, ["frame 1", "shape (3, 3)", "4x4"]),
    "pose_non_finite": (pose_non_finite, ["frame 2", "non-finite"]),
    "nero_pose_wrong_shape": (nero_pose_wrong_shape, ["pose is shape (2, 4)", "3x4"]),
    "exr_nan": (exr_nan, ["NaN/Inf", "row 4, column 5"]),
    "unknown_camera_model": (unknown_camera_model, ["unknown camera model 'WEIRD_MODEL'",
                                                    "image_undistorter"]),
    "unsupported_camera_model": (unsupported_camera_model, ["OPENCV_FISHEYE is not supported",
                                                            "image_undistorter"]),
    "no_known_format": (no_known_format, ["no known format", "transforms_train.json",
                                          "camera.pkl", "sparse/0"]),
    "missing_folder": (missing_folder, ["scene folder not found"]),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_exits_2_with_short_message(tmp_path, capsys, case):
    build, expected = CASES[case]
    root = tmp_path / case
    names_file = build(root)
    rc = cli.main(["info", str(root if case != "missing_folder" else tmp_path / names_file)])
    out, err = capsys.readouterr()
    assert rc == 2
    lines = err.strip().splitlines()
    assert 1 <= len(lines) <= 2, err
    assert lines[0].startswith("voxnero info: error: ")
    assert "Traceback" not in err and "Traceback" not in out
    assert names_file in err, err
    assert "fix:" in err, err
    for s in expected:
        assert s in err, f"{s!r} not in {err!r}"


def test_info_on_a_good_scene_and_info_json(tmp_path, capsys):
    make_blender(tmp_path / "s", n={"train": 3, "test": 2}, rgba=True)
    rc = cli.main(["info", str(tmp_path / "s"), "white_bg=true", "--out", str(tmp_path / "o")])
    out, err = capsys.readouterr()
    assert rc == 0 and err == ""
    assert "format      blender" in out and "train: 3 views, 40x32" in out
    assert "fx=48.000 fy=46.000 cx=21.000 cy=15.500" in out and "background  alpha" in out
    info = json.loads((tmp_path / "o" / "info.json").read_text())
    assert info["format"] == "blender" and info["splits"]["test"]["views"] == 2
    assert info["splits"]["train"]["alpha"] is True and info["up"] == [0, 0, 1]
    assert info["normalisation"]["method"].startswith("cameras")


def test_overrides_after_out_documented_order(tmp_path, capsys):
    make_blender(tmp_path / "s", n={"train": 2})
    assert cli.main(["info", str(tmp_path / "s"), "--out", str(tmp_path / "o"),
                     "white_bg=true"]) == 0


def test_info_on_a_run_folder(tmp_path, capsys):
    (tmp_path / "config.yaml").write_text("shape:\n  iters: 10\n")
    (tmp_path / "mesh.ply").write_text("x")
    assert cli.main(["info", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "run" in out and "['shape']" in out and "mesh.ply" in out


def test_bad_override_is_a_config_error(tmp_path, capsys):
    make_blender(tmp_path, n={"train": 2})
    assert cli.main(["info", str(tmp_path), "radius=abc"]) == 2
    assert "radius" in capsys.readouterr().err


def test_real_process_exit_code(tmp_path):
    (tmp_path / "empty").mkdir()
    r = subprocess.run([sys.executable, "-m", "voxnero", "info", str(tmp_path / "empty")],
                       capture_output=True, text=True, timeout=120,
                       cwd=Path(__file__).resolve().parents[1])
    assert r.returncode == 2
    assert "no known format" in r.stderr and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) <= 2
