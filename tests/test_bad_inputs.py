"""Bad inputs at the door (issue 23): every command refuses bad cameras and bad numeric settings
before any work, with exit code 2, one or two lines on stderr naming the file (and frame) or the
key, a fix, and no traceback.

Table-driven, in process through :func:`voxnero.cli.main` like ``tests/test_cli_errors.py``.
Scenes are the tiny analytic fixtures of ``tests/fixtures/scenes.py`` with one defect each; the
numeric settings are every key of every command (``tests/fixtures/config_settings.py``), each
given NaN, ±Inf or a value just past its range. Each case would otherwise start work, so the
commands also get overrides that keep such work short (``FAST``), placed before the bad one.
"""

from __future__ import annotations

import pickle
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.fixtures.config_settings import is_list, numeric_fields, out_of_range
from tests.fixtures.scenes import edit_json, make_blender, make_colmap, make_nero
from voxnero import cli
from voxnero.io.exr import write_exr

FAST = {
    "shape": ["--preset", "tiny", "--no-progress", "--no-eval", "iters=1", "mesh_res=16",
              "grid.init_candidates=[]", "grid.res=[8]", "grid.upsample_at=[]"],
    "material": ["--preset", "tiny", "--no-progress", "iters=1"],
    "eval": ["--preset", "tiny"],
    "relight": ["--orbit", "--no-progress", "orbit.frames=1", "orbit.size=8", "spp=1"],
    "batch": ["--preset", "tiny", "--no-progress"],
    "info": [],
    "synth": ["--preset", "tiny", "n_train=1", "n_test=0", "resolution=8", "spp=1"],
}
"""Overrides (and flags) that keep a command short should it wrongly accept the bad input."""


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> dict[str, Path]:
    """Good inputs shared by the cases: a Blender scene, a mesh file, a relight asset and an
    env map, and a batch manifest path that does not exist (so a batch that accepted its
    settings stops at once)."""
    from tests.fixtures.assets import textured_sphere, write_assets

    root = tmp_path_factory.mktemp("good")
    make_blender(root / "scene", n={"train": 3, "test": 1})
    (root / "mesh.ply").write_text("ply\n")  # read only after the settings and the scene
    _, tm, _ = textured_sphere(16)
    glb, _ = write_assets(root, tm)
    write_exr(root / "env.exr", np.full((8, 16, 3), 0.5, np.float32), half=False)
    return {"scene": root / "scene", "mesh": root / "mesh.ply", "glb": glb,
            "env": root / "env.exr", "manifest": root / "no_manifest.yaml"}


def argv_for(command: str, inputs: dict[str, Path], out: Path, target: Path | None = None,
             extra: tuple[str, ...] = ()) -> list[str]:
    """The command line of ``command`` on the good inputs (``target`` replaces the scene)."""
    scene = str(target or inputs["scene"])
    head = {
        "info": ["info", scene],
        "shape": ["shape", scene, "--out", str(out)],
        "material": ["material", str(inputs["mesh"]), "--scene", scene, "--out", str(out)],
        "eval": ["eval", str(inputs["mesh"]), "--scene", scene, "--out", str(out)],
        "relight": ["relight", str(inputs["glb"]), "--env", str(inputs["env"]), "--out",
                    str(out)],
        "batch": ["batch", str(inputs["manifest"]), "--out", str(out)],
        "synth": ["synth", "sphere", "--out", str(out)],
    }[command]
    return head + FAST[command] + list(extra)


def run_cli(argv: list[str], capsys) -> tuple[int, str]:
    """Run ``voxnero argv`` in process; (exit code, stderr), asserting nothing leaked."""
    try:
        rc = cli.main(argv)
    except Exception as e:  # noqa: BLE001 - a traceback is exactly what is tested against
        out, err = capsys.readouterr()
        pytest.fail(f"{type(e).__name__} escaped the CLI: {e}\n{err[-2000:]}")
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err, err
    return rc, err


def assert_clean_error(rc: int, err: str, command: str, named: list[str]) -> None:
    """Exit 2; one or two lines ``voxnero CMD: error: ...`` with a fix; every string of
    ``named`` (the file, the frame, the key=value) in the message."""
    assert rc == 2, f"exit {rc}, stderr: {err[-2000:]}"
    lines = err.strip().splitlines()
    assert 1 <= len(lines) <= 2 and lines[0].startswith(f"voxnero {command}: error: "), err
    assert "fix:" in err, err
    for s in named:
        assert s in err, f"{s!r} not in {err!r}"


# --------------------------------------------------------------------------------------------
# scenes with one bad camera (every format); checked by info and by the commands that load them
# --------------------------------------------------------------------------------------------

def _pose(i: int, fn: Callable[[np.ndarray], np.ndarray]):
    """JSON edit: frame i's transform_matrix -> fn(matrix)."""
    def edit(meta):
        meta["frames"][i]["transform_matrix"] = fn(np.asarray(meta["frames"][i]
                                                              ["transform_matrix"])).tolist()
    return edit


def _scaled(m):
    m[:3, :3] *= 3
    return m


def _sheared(m):
    m[0, :3] += 0.05 * m[1, :3]
    return m


def _singular(m):
    m[:3, :3] = 0
    return m


def _mirror(m):
    m[:3, 0] *= -1
    return m


def blender(edit, split: str = "train", ngp_keys: bool = False):
    """Builder of a Blender scene whose ``transforms_<split>.json`` got ``edit``."""
    def build(root: Path) -> Path:
        make_blender(root, n={"train": 3, "test": 2}, ngp_keys=ngp_keys)
        edit_json(root / f"transforms_{split}.json", edit)
        return root
    return build


def nero(edit_camera: Callable[[np.ndarray, np.ndarray], None], view: int = 1):
    """Builder of a NeRO scene whose view ``view`` has ``edit_camera(w2c, K)`` applied."""
    def build(root: Path) -> Path:
        make_nero(root, n=3, with_depth=False)
        with open(root / f"{view}-camera.pkl", "rb") as fh:
            w2c, K = (np.asarray(a, np.float64) for a in pickle.load(fh))
        edit_camera(w2c, K)
        with open(root / f"{view}-camera.pkl", "wb") as fh:
            pickle.dump([w2c, K], fh)
        return root
    return build


def colmap(old: str, new: str):
    """Builder of a text COLMAP scene whose cameras.txt has ``old`` replaced by ``new``."""
    def build(root: Path) -> Path:
        make_colmap(root, n=3)
        p = root / "sparse" / "0" / "cameras.txt"
        p.write_text(p.read_text().replace(old, new))
        return root
    return build


def _set(**kw):
    return lambda meta: meta.update(**kw)


def _set_frame(i, **kw):
    return lambda meta: meta["frames"][i].update(**kw)


def _nero_scale(w2c, K):
    w2c[:, :3] *= 3


def _nero_singular(w2c, K):
    w2c[:, :3] = 0


def _nero_mirror(w2c, K):
    w2c[2, :3] *= -1


def _nero_pp_outside(w2c, K):
    K[0, 2] = -3.0


def _nero_not_pinhole(w2c, K):
    K[2, 2] = 0.0


SCENES: dict[str, tuple[Callable[[Path], Path], list[str]]] = {
    # Blender / NeRF-synthetic
    "rotation_scaled_x3": (blender(_pose(1, _scaled)),
                           ["transforms_train.json", "frame 1 (./train/r_1)", "not orthonormal"]),
    "rotation_sheared": (blender(_pose(2, _sheared)),
                         ["transforms_train.json", "frame 2 (./train/r_2)", "not orthonormal"]),
    "pose_singular": (blender(_pose(0, _singular)),
                      ["transforms_train.json", "frame 0 (./train/r_0)", "singular"]),
    "pose_mirrored": (blender(_pose(1, _mirror)), ["transforms_train.json", "frame 1", "mirror"]),
    "pose_transposed": (blender(_pose(1, lambda m: m.T.copy())),
                        ["transforms_train.json", "frame 1", "transposed"]),
    "camera_angle_x_0": (blender(_set(camera_angle_x=0.0)),
                         ["transforms_train.json", "frame 0", "camera_angle_x=0.0"]),
    "camera_angle_x_pi": (blender(_set(camera_angle_x=float(np.pi))),
                          ["transforms_train.json", "frame 0", "camera_angle_x=3.14159"]),
    "camera_angle_y_0": (blender(_set_frame(1, camera_angle_y=0.0)),
                         ["transforms_train.json", "frame 1", "camera_angle_y=0.0"]),
    "principal_point_outside": (blender(_set_frame(2, cx=55.0), ngp_keys=True),
                                ["transforms_train.json", "frame 2", "principal point (55"]),
    "principal_point_negative": (blender(_set(cy=-1.0), ngp_keys=True),
                                 ["transforms_train.json", "frame 0", "principal point"]),
    "image_size_not_numbers": (blender(_set(w="wide", h=32), ngp_keys=True),
                               ["transforms_train.json", "frame 0", "w='wide'"]),
    "test_split_rotation_scaled": (blender(_pose(1, _scaled), split="test"),
                                   ["transforms_test.json", "frame 1 (./test/r_1)",
                                    "not orthonormal"]),
    # NeRO
    "nero_rotation_scaled": (nero(_nero_scale), ["1-camera.pkl", "view 1 (1.png)",
                                                 "not orthonormal"]),
    "nero_singular": (nero(_nero_singular, view=2), ["2-camera.pkl", "view 2", "singular"]),
    "nero_mirrored": (nero(_nero_mirror), ["1-camera.pkl", "view 1", "mirror"]),
    "nero_principal_point_outside": (nero(_nero_pp_outside, view=0),
                                     ["0-camera.pkl", "view 0", "principal point"]),
    "nero_K_not_pinhole": (nero(_nero_not_pinhole), ["1-camera.pkl", "pinhole"]),
    # COLMAP
    "colmap_focal_zero": (colmap(" 41.0 43.0 ", " 0.0 43.0 "),
                          ["cameras.txt", "image 1 (img_00.png)", "focal lengths"]),
    "colmap_principal_point_outside": (colmap(" 19.2 14.7", " 119.2 14.7"),
                                       ["cameras.txt", "image 1", "principal point (119.2"]),
}
"""Scene defect -> (builder of the bad scene, strings the message must contain)."""


@pytest.mark.parametrize("case", list(SCENES))
def test_info_refuses_bad_cameras(tmp_path, capsys, case):
    build, named = SCENES[case]
    root = build(tmp_path / case)
    rc, err = run_cli(["info", str(root)], capsys)
    assert_clean_error(rc, err, "info", named)


COMMANDS_ON_BAD_SCENES = [
    ("shape", "rotation_scaled_x3"), ("shape", "camera_angle_x_0"),
    ("shape", "nero_rotation_scaled"), ("material", "rotation_scaled_x3"),
    ("material", "colmap_principal_point_outside"), ("eval", "test_split_rotation_scaled"),
]
"""The training and evaluation commands load their scene through the same checks as info."""


@pytest.mark.parametrize("command, case", COMMANDS_ON_BAD_SCENES)
def test_commands_refuse_bad_cameras_before_work(tmp_path, capsys, inputs, command, case):
    build, named = SCENES[case]
    root = build(tmp_path / case)
    out = tmp_path / "out"
    rc, err = run_cli(argv_for(command, inputs, out, target=root), capsys)
    assert_clean_error(rc, err, command, named)
    assert not (out / "mesh.ply").exists() and not (out / "checkpoint.pt").exists()


@pytest.mark.parametrize("case", ["camera_angle_x_0", "rotation_scaled_x3"])
def test_relight_refuses_bad_cameras_file(tmp_path, capsys, inputs, case):
    build, named = SCENES[case]
    root = build(tmp_path / case)
    argv = ["relight", str(inputs["glb"]), "--env", str(inputs["env"]), "--out",
            str(tmp_path / "out"), "--cameras", str(root / "transforms_train.json"),
            "--no-progress", "spp=1", "scale=0.25"]
    rc, err = run_cli(argv, capsys)
    assert_clean_error(rc, err, "relight", named)


def test_relight_refuses_an_env_map_too_bright_for_float32(tmp_path, capsys, inputs):
    """An env map of 3e38 used to give EXRs full of Inf with exit 0."""
    env = tmp_path / "sun.exr"
    img = np.full((8, 16, 3), 0.5, np.float32)
    img[2, 3] = 3e38
    write_exr(env, img, half=False)
    argv = ["relight", str(inputs["glb"]), "--env", str(env), "--out", str(tmp_path / "out"),
            *FAST["relight"]]
    rc, err = run_cli(argv, capsys)
    assert_clean_error(rc, err, "relight", ["sun.exr", "overflow", "env_scale"])
    assert not (tmp_path / "out" / "exr").exists()


# --------------------------------------------------------------------------------------------
# numeric settings: non-finite or out of range, refused before any work
# --------------------------------------------------------------------------------------------

SETTINGS = [
    # shape (the lr_sdf=nan, and sampling.rays=0 that trained nothing with exit 0)
    ("shape", "optim.lr_sdf=nan", "shape.optim.lr_sdf=nan"),
    ("shape", "optim.lr_sdf=1e30", "shape.optim.lr_sdf=1e+30"),
    ("shape", "sampling.rays=0", "shape.sampling.rays=0"),
    ("shape", "grid.upsample_at=[nan]", "shape.grid.upsample_at=[nan]"),
    ("shape", "neus.s_start=-1", "shape.neus.s_start=-1.0"),
    ("shape", "loss.eikonal=nan", "shape.loss.eikonal=nan"),
    ("shape", "light.env_init=0", "shape.light.env_init=0.0"),
    ("shape", "optim.decay=inf", "shape.optim.decay=inf"),
    ("shape", "seed=-1", "shape.seed=-1"),
    ("shape", "threads=-1", "shape.threads=-1"),
    # material (lr_material=1e30 was a traceback)
    ("material", "lr_material=1e30", "material.lr_material=1e+30"),
    ("material", "lr_material=nan", "material.lr_material=nan"),
    ("material", "lr_env=-0.1", "material.lr_env=-0.1"),
    ("material", "lr_decay=0", "material.lr_decay=0.0"),
    ("material", "field.init_albedo=2", "material.field.init_albedo=2.0"),
    ("material", "light.upsample_at=nan", "material.light.upsample_at=nan"),
    ("material", "texture_size=1e9", "material.texture_size=1000000000"),
    # eval
    ("eval", "voxel=nan", "eval.voxel=nan"),
    ("eval", "voxel=inf", "eval.voxel=inf"),
    ("eval", "views=[-1]", "eval.views=[-1]"),
    ("eval", "material_spp=[8,8,100000]", "eval.material_spp=[8, 8, 100000]"),
    # relight (exposure 1e30 / yaw inf were tracebacks; 200 and nan wrote Inf/NaN EXRs)
    ("relight", "exposure=1e30", "relight.exposure=1e+30"),
    ("relight", "exposure=200", "relight.exposure=200"),
    ("relight", "exposure=nan", "relight.exposure=nan"),
    ("relight", "yaw_deg=inf", "relight.yaw_deg=inf"),
    ("relight", "env_scale=nan", "relight.env_scale=nan"),
    ("relight", "chunk=0", "relight.chunk=0"),
    ("relight", "orbit.fov_deg=180", "relight.orbit.fov_deg=180.0"),
    ("relight", "orbit.elevation_deg=nan", "relight.orbit.elevation_deg=nan"),
    ("relight", "threads=-1", "relight.threads=-1"),
    # batch: its own section and every stage's, before Ray starts
    ("batch", "batch.num_cpus=nan", "batch.num_cpus=nan"),
    ("batch", "batch.lock_timeout_s=-1", "batch.lock_timeout_s=-1.0"),
    ("batch", "shape.optim.lr_sdf=nan", "shape.optim.lr_sdf=nan"),
    ("batch", "material.lr_material=1e30", "material.lr_material=1e+30"),
    ("batch", "eval.voxel=nan", "eval.voxel=nan"),
    # info's scene options
    ("info", "radius=nan", "radius=nan"),
    ("info", "radius=-1", "radius=-1.0"),
    ("info", "radius=inf", "radius=inf"),
    ("info", "radius=0", "radius=0.0"),
    # synth
    ("synth", "distance=0", "synth.distance=0.0"),
    ("synth", "env.scale=nan", "synth.env.scale=nan"),
    ("synth", "sphere.radius=-1", "synth.sphere.radius=-1.0"),
]
"""(command, bad override, the key=value the message must name)."""


@pytest.mark.parametrize("command, override, named", SETTINGS,
                         ids=[f"{c}:{o}" for c, o, _ in SETTINGS])
def test_bad_setting_is_refused_before_work(tmp_path, capsys, inputs, command, override, named):
    out = tmp_path / "out"
    rc, err = run_cli(argv_for(command, inputs, out, extra=(override,)), capsys)
    assert_clean_error(rc, err, command, [named])
    assert not out.exists() or not any(out.iterdir()), sorted(out.iterdir())


# --------------------------------------------------------------------------------------------
# hypothesis: any numeric key of any command, any non-finite or out-of-range value
# --------------------------------------------------------------------------------------------

NUMERIC = numeric_fields()


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.sampled_from(NUMERIC), st.data())
def test_any_bad_number_is_refused_by_its_command(tmp_path, capsys, inputs, entry, data):
    """Every command with settings: exit 2, one message naming the key, before any output is
    written (batch takes its overrides with their section, the others without)."""
    key, cls, f = entry
    value = data.draw(st.sampled_from(out_of_range(cls.RANGES[f.name])), label="value")
    command, *rest = key.split(".")
    name = ".".join(rest)
    given = key if command == "batch" else name
    override = f"{given}=[{value!r}]" if is_list(cls, f.name) else f"{given}={value!r}"
    out = tmp_path / f"out_{data.draw(st.integers(0, 10 ** 9), label='dir')}"
    rc, err = run_cli(argv_for(command, inputs, out, extra=(override,)), capsys)
    assert_clean_error(rc, err, command, [name if command == "info" else key])
    assert not out.exists()


# --------------------------------------------------------------------------------------------
# unusable --out, and an output folder removed during the run
# --------------------------------------------------------------------------------------------

OUT_COMMANDS = ["shape", "material", "eval", "relight", "batch", "synth"]


def _existing_file(tmp: Path) -> tuple[Path, str]:
    (tmp / "taken").write_text("not a folder")
    return tmp / "taken", "is an existing file"


def _under_a_file(tmp: Path) -> tuple[Path, str]:
    (tmp / "plain.txt").write_text("a file")
    return tmp / "plain.txt" / "out", "plain.txt is a file"


def _read_only(tmp: Path) -> tuple[Path, str]:
    (tmp / "ro").mkdir()
    (tmp / "ro").chmod(0o555)
    return tmp / "ro", "not writable"


BAD_OUTS: dict[str, Callable[[Path], tuple[Path, str]]] = {
    "existing_file": _existing_file, "under_a_file": _under_a_file, "read_only": _read_only}
"""--out defect -> builder returning (the --out path, what the message must say)."""


@pytest.fixture
def batch_manifest(tmp_path) -> Path:
    """A manifest of one scene folder that does not exist (a batch that got past --out would
    only write an error row)."""
    path = tmp_path / "manifest.yaml"
    path.write_text("scenes:\n  - nowhere\n")
    return path


@pytest.mark.parametrize("command", OUT_COMMANDS)
@pytest.mark.parametrize("case", list(BAD_OUTS))
def test_unusable_out_is_refused(tmp_path, capsys, monkeypatch, inputs, batch_manifest, command,
                                 case):
    """--out an existing file, a path under a file or a read-only folder were FileExistsError /
    NotADirectoryError / PermissionError tracebacks."""
    import os

    from voxnero.safety import folder

    out, said = BAD_OUTS[case](tmp_path)
    if case == "read_only" and os.geteuid() == 0:  # root writes anywhere: deny as the OS would
        real = os.open

        def deny(path, *a, **k):
            if str(path).startswith(str(out)):
                raise PermissionError(13, "Permission denied", str(path))
            return real(path, *a, **k)

        monkeypatch.setattr(folder.os, "open", deny)
    argv = argv_for(command, {**inputs, "manifest": batch_manifest}, out)
    rc, err = run_cli(argv, capsys)
    assert_clean_error(rc, err, command, [str(out), said])
    if case == "existing_file":
        assert out.read_text() == "not a folder"


def _remove_at_step(module, name: str, out: Path, at: int, monkeypatch) -> None:
    """Wrap ``module.name`` (a training step) to delete ``out`` when it is called the
    ``at``-th time."""
    import shutil

    orig = getattr(module, name)
    calls = {"n": 0}

    def step(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == at:
            shutil.rmtree(out)
        return orig(self, *a, **k)

    monkeypatch.setattr(module, name, step)


def _sphere_mesh(path: Path) -> Path:
    """The fixture scenes' sphere as a mesh file in their input frame."""
    import open3d as o3d

    from tests.fixtures.scenes import SPHERE_C, SPHERE_R

    mesh = o3d.geometry.TriangleMesh.create_sphere(SPHERE_R, 12).translate(SPHERE_C)
    o3d.io.write_triangle_mesh(str(path), mesh)
    return path


@pytest.mark.parametrize("command", ["shape", "material"])
def test_output_folder_removed_mid_run(tmp_path, capsys, monkeypatch, inputs, command):
    """The folder deleted during training was a RuntimeError / FileNotFoundError traceback."""
    from voxnero.material.trainer import MaterialTrainer
    from voxnero.shape.trainer import ShapeTrainer

    out = tmp_path / "out"
    if command == "shape":
        _remove_at_step(ShapeTrainer, "train_step", out, 2, monkeypatch)
        extra: tuple[str, ...] = ("iters=4", "ckpt_every_s=0")
    else:
        inputs = {**inputs, "mesh": _sphere_mesh(tmp_path / "sphere.ply")}
        _remove_at_step(MaterialTrainer, "train_step", out, 2, monkeypatch)
        extra = ("iters=4", "checkpoint_every=1", "eval_views=0", "texture_size=16",
                 "light.env_height=[8]", "bg_batch=64", "batch=16")
    rc, err = run_cli(argv_for(command, inputs, out, extra=extra), capsys)
    assert_clean_error(rc, err, command, [str(out), "removed"])
    assert not (out / "mesh.ply").exists() and not (out / "model.glb").exists()


# --------------------------------------------------------------------------------------------
# the last row: a 1x1 env map, a missing texture, an empty CSV manifest
# --------------------------------------------------------------------------------------------

def _env_1x1(tmp: Path, inputs: dict[str, Path]) -> list[str]:
    write_exr(tmp / "tiny_env.exr", np.full((1, 1, 3), 0.5, np.float32), half=False)
    return ["relight", str(inputs["glb"]), "--env", str(tmp / "tiny_env.exr"), "--out",
            str(tmp / "out"), *FAST["relight"]]


def _missing_texture(tmp: Path, inputs: dict[str, Path]) -> list[str]:
    import shutil

    src = inputs["glb"].parent
    (tmp / "asset").mkdir()
    for name in ("model.obj", "model.mtl", "model_metallic.png", "model_roughness.png"):
        shutil.copy(src / name, tmp / "asset" / name)  # model_albedo.png left behind
    return ["relight", str(tmp / "asset" / "model.obj"), "--env", str(inputs["env"]), "--out",
            str(tmp / "out"), *FAST["relight"]]


def _csv(text: str) -> Callable[[Path, dict[str, Path]], list[str]]:
    def build(tmp: Path, inputs: dict[str, Path]) -> list[str]:
        (tmp / "scenes.csv").write_text(text)
        return ["batch", str(tmp / "scenes.csv"), "--out", str(tmp / "out"), *FAST["batch"]]
    return build


LAST_ROW: dict[str, tuple[Callable[[Path, dict[str, Path]], list[str]], list[str]]] = {
    "env_map_1x1": (_env_1x1, ["tiny_env.exr", "1 x 1 pixels", "width = 2 x height"]),
    "missing_texture": (_missing_texture, ["model_albedo.png", "map_Kd of model.mtl",
                                           "model.glb"]),
    "empty_csv_manifest": (_csv(""), ["scenes.csv", "empty", "path,name,overrides"]),
    "csv_manifest_header_only": (_csv("path,name,overrides\n"),
                                 ["scenes.csv", "no scenes", "one line per scene"]),
}
"""Case -> (builder of the command line, strings the message must contain: file, fix)."""


@pytest.mark.parametrize("case", list(LAST_ROW))
def test_last_row_names_the_file_and_the_fix(tmp_path, capsys, inputs, case):
    build, named = LAST_ROW[case]
    argv = build(tmp_path, inputs)
    rc, err = run_cli(argv, capsys)
    assert_clean_error(rc, err, argv[0], named)
    assert not (tmp_path / "out").exists()
