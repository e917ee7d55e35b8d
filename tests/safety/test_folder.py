"""voxnero/safety/folder.py: the lock (live and stale), atomic outputs (a failing run leaves a good
folder byte-identical), and the folder's usability checks, through the commands."""

from __future__ import annotations

import errno
import os
import signal
import socket
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from tests.safety.safety_helpers import blender_scene, run_cli, shape_argv, snapshot
from voxnero.errors import RunFolderError
from voxnero.safety import folder as folder_mod
from voxnero.safety.folder import LOCK, RunFolder


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return blender_scene(tmp_path_factory.mktemp("runs") / "scene")


# ------------------------------------------------------------------------------------- lock
def test_a_second_run_into_a_held_folder_is_refused(tmp_path, capsys, scene):
    """Two commands into one --out: no lock made one die with a FileNotFoundError traceback."""
    out = tmp_path / "out"
    with RunFolder(out, "shape", log=lambda s: None):
        rc, _, err = run_cli(shape_argv(scene, out), capsys)
        assert rc == 2, err
        assert "another run holds this folder" in err and str(out) in err
        assert f"pid {os.getpid()} on host {socket.gethostname()}" in err and "fix:" in err
        assert not (out / "mesh.ply").exists() and (out / LOCK).is_file()
    assert not (out / LOCK).exists()  # released with the run


def test_a_stale_lock_of_a_killed_process_is_taken_over(tmp_path, capsys, scene):
    """A run killed with -9 leaves its lock file; nobody holds it, so the next run goes on."""
    out = tmp_path / "out"
    code = textwrap.dedent(f"""
        import os, signal
        from voxnero.safety.folder import RunFolder
        with RunFolder({str(out)!r}, "shape"):
            os.kill(os.getpid(), signal.SIGKILL)
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True)
    assert proc.returncode == -signal.SIGKILL and (out / LOCK).is_file()
    rc, stdout, err = run_cli(shape_argv(scene, out), capsys)
    assert rc == 0, err
    assert "took over the stale lock" in stdout and "it no longer runs" in stdout
    assert (out / "mesh.ply").is_file() and not (out / LOCK).exists()


@pytest.mark.parametrize("host, alive, refused", [
    ("this", False, False), ("this", True, True), ("elsewhere", False, True)])
def test_without_flock_the_record_decides(tmp_path, monkeypatch, host, alive, refused):
    """On a filesystem without flock: same host and pid gone -> stale; pid alive, or another
    host (which cannot be asked) -> refused, the latter with the lock file to delete."""
    def no_flock(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(folder_mod.fcntl, "flock", no_flock)
    monkeypatch.setattr(folder_mod, "pid_alive", lambda pid: alive)
    out = tmp_path / "out"
    out.mkdir()
    name = socket.gethostname() if host == "this" else "other-node"
    (out / LOCK).write_text(f'{{"pid": 999999, "host": "{name}", "command": "shape"}}')
    if refused:
        with pytest.raises(RunFolderError, match="pid 999999") as e:
            RunFolder(out, "material", log=lambda s: None).__enter__()
        assert (str(out / LOCK) in str(e.value)) == (host != "this")
    else:
        with RunFolder(out, "material", log=lambda s: None) as run:
            assert run.stale and run.stale["pid"] == 999999


# -------------------------------------------------------------------------- atomic outputs
@pytest.fixture
def good_folder(tmp_path):
    """A finished run's folder (its bytes stand for any good outputs)."""
    out = tmp_path / "good"
    (out / "exr").mkdir(parents=True)
    (out / "config.yaml").write_text("good: {iters: 1}\n")
    (out / "model.glb").write_bytes(bytes(range(256)))
    (out / "metrics.json").write_text('{"cd": 0.001}\n')
    (out / "orbit_000.png").write_bytes(b"\x89PNG good")
    (out / "exr" / "orbit_000.exr").write_bytes(b"good exr")
    return out


def _sphere_mesh(path):
    import open3d as o3d

    from tests.fixtures.scenes import SPHERE_C, SPHERE_R

    mesh = o3d.geometry.TriangleMesh.create_sphere(SPHERE_R, 12).translate(SPHERE_C)
    o3d.io.write_triangle_mesh(str(path), mesh)
    return path


def test_failing_runs_leave_a_good_folder_byte_identical(tmp_path, capsys, monkeypatch, scene,
                                                         good_folder):
    """material / eval / relight failing after they started used to overwrite config.yaml (and
    relight the views it had rendered)."""
    from tests.fixtures.assets import textured_sphere, write_assets
    from tests.fixtures.scenes import edit_json
    from voxnero.io.exr import write_exr
    from voxnero.relight.render import Relighter

    before = snapshot(good_folder)
    mesh = _sphere_mesh(tmp_path / "sphere.ply")
    # material: the scene's cameras are refused once the run has begun
    bad = blender_scene(tmp_path / "bad_scene")

    def scale_frame_1(meta):
        meta["frames"][1]["transform_matrix"] = (
            np.asarray(meta["frames"][1]["transform_matrix"]) * [[3], [3], [3], [1]]).tolist()

    edit_json(bad / "transforms_train.json", scale_frame_1)
    rc, _, err = run_cli(["material", str(mesh), "--scene", str(bad), "--out", str(good_folder),
                          "--preset", "tiny", "--no-progress", "iters=1"], capsys)
    assert rc == 2 and "not orthonormal" in err, err
    assert snapshot(good_folder) == before
    # eval: a scene without ground truth
    rc, _, err = run_cli(["eval", str(mesh), "--scene", str(scene), "--out", str(good_folder),
                          "--preset", "tiny"], capsys)
    assert rc == 2, err
    assert snapshot(good_folder) == before
    # relight: the second view fails after the first one was written
    _, tm, _ = textured_sphere(16)
    glb, _ = write_assets(tmp_path, tm)
    write_exr(tmp_path / "env.exr", np.full((8, 16, 3), 0.5, np.float32), half=False)
    real = Relighter.render
    calls = {"n": 0}

    def render(self, *a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RunFolderError("simulated failure in view 2")
        return real(self, *a, **k)

    monkeypatch.setattr(Relighter, "render", render)
    rc, _, err = run_cli(["relight", str(glb), "--env", str(tmp_path / "env.exr"), "--out",
                          str(good_folder), "--orbit", "--no-progress", "orbit.frames=2",
                          "orbit.size=8", "spp=1"], capsys)
    assert rc == 2 and "simulated failure" in err, err
    assert calls["n"] == 2
    assert snapshot(good_folder) == before


def test_a_successful_run_replaces_the_outputs_and_cleans_up(tmp_path, capsys, scene):
    out = tmp_path / "out"
    rc, _, err = run_cli(shape_argv(scene, out), capsys)
    assert rc == 0, err
    names = {p.name for p in out.iterdir()}
    assert {"mesh.ply", "sdf.npz", "envmap.exr", "shape.json", "config.yaml",
            "checkpoint.pt"} <= names
    assert not names & {LOCK, ".partial"}


def test_commit_moves_staged_files_into_place(tmp_path):
    out = tmp_path / "run"
    with RunFolder(out, "test", log=lambda s: None) as run:
        (run.staging / "sub").mkdir()
        (run.staging / "sub" / "a.txt").write_text("new")
        (out / "sub").mkdir()
        (out / "sub" / "a.txt").write_text("old")
        assert run.commit() == [out / "sub" / "a.txt"]
    assert (out / "sub" / "a.txt").read_text() == "new"
    assert sorted(p.name for p in out.iterdir()) == ["sub"]
