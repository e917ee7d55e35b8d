"""One scene's task without Ray: stage command lines, skip when finished, metrics, error rows."""

from __future__ import annotations

import json
import os

import pytest

from voxnero.batch.tasks import (
    LOCK,
    SceneJob,
    StageKilled,
    _Lock,
    collect_metrics,
    is_finished,
    read_result,
    run_scene,
    stage_commands,
    write_result,
)
from voxnero.cli import build_parser, parse_command_line


def _job(tmp_path, scene, **kw) -> SceneJob:
    return SceneJob(name="s", scene=str(scene), out=str(tmp_path / "out" / "s"),
                    preset="standard", **kw)


def test_stage_commands_parse_with_the_real_cli(tmp_path):
    scene = tmp_path / "scene"
    (scene / "gt").mkdir(parents=True)
    job = _job(tmp_path, scene, overrides=["shape.iters=5", "material.iters=3"],
               eval_overrides=["eval.voxel=0.02"])
    stages = stage_commands(job)
    assert [s["name"] for s in stages] == ["reconstruct", "eval"]
    parser = build_parser()
    rec = parse_command_line(parser, stages[0]["argv"])
    assert rec.command == "reconstruct" and rec.target == str(scene)
    assert rec.out == job.out and rec.overrides == ["shape.iters=5", "material.iters=3"]
    assert rec.no_progress and rec.device == "auto"
    ev = parse_command_line(parser, stages[1]["argv"])
    assert ev.target == os.path.join(job.out, "shape") and ev.scene == str(scene)
    assert ev.out == os.path.join(job.out, "eval") and ev.overrides == ["eval.voxel=0.02"]


def test_stage_commands_shape_only_and_no_ground_truth(tmp_path):
    scene = tmp_path / "scene"
    scene.mkdir()
    stages = stage_commands(_job(tmp_path, scene, command="shape"))
    assert [s["name"] for s in stages] == ["shape"]  # no gt/ -> no eval
    args = parse_command_line(build_parser(), stages[0]["argv"])
    assert args.command == "shape" and args.out == os.path.join(str(tmp_path / "out" / "s"),
                                                                "shape")
    (scene / "gt").mkdir()
    assert len(stage_commands(_job(tmp_path, scene, command="shape", eval=False))) == 1


def test_collect_metrics(tmp_path):
    (tmp_path / "eval").mkdir()
    (tmp_path / "material").mkdir()
    (tmp_path / "eval" / "metrics.json").write_text(json.dumps(
        {"chamfer": {"cd": 0.0123}, "normals": {"mean_deg": 4.5}}))
    (tmp_path / "material" / "metrics.json").write_text(json.dumps(
        {"novel_view": {"psnr": 27.5}}))
    (tmp_path / "material" / "model.glb").write_bytes(b"glTF")
    m = collect_metrics(tmp_path)
    assert (m["chamfer"], m["normal_deg"], m["psnr"]) == (0.0123, 4.5, 27.5)
    assert m["mesh"] is None and m["model"].endswith("model.glb")
    (tmp_path / "eval" / "metrics.json").write_text(json.dumps({"normals": "not evaluated"}))
    assert collect_metrics(tmp_path)["normal_deg"] is None


def test_finished_scene_is_skipped_without_running(tmp_path):
    job = _job(tmp_path, tmp_path / "does-not-exist")
    write_result(job.out, {"scene": "s", "status": "ok", "chamfer": 0.01})
    assert is_finished(job.out)
    row = run_scene(job)
    assert row["status"] == "skipped" and row["chamfer"] == 0.01
    assert sorted(p.name for p in (tmp_path / "out" / "s").iterdir()) == ["result.json"]


def test_lock_waits_then_gives_up(tmp_path):
    with _Lock(tmp_path / LOCK, 1.0):
        with pytest.raises(StageKilled, match="previous attempt still runs"):
            with _Lock(tmp_path / LOCK, 0.3):
                pass
    with _Lock(tmp_path / LOCK, 0.3):  # free again
        pass


def test_unreadable_scene_gives_an_error_row(tmp_path):
    """A scene whose poses parse but whose images are missing fails inside its stage process."""
    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "transforms_train.json").write_text(json.dumps(
        {"camera_angle_x": 0.7, "frames": [{"file_path": "./train/r_0",
                                            "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0],
                                                                 [0, 0, 1, 4], [0, 0, 0, 1]]}]}))
    job = _job(tmp_path, scene)
    row = run_scene(job)
    assert row["status"] == "error" and row["attempts"] == 1
    assert row["error"].startswith("reconstruct: ") and "r_0" in row["error"]
    assert 100 < row["peak_mem_mb"] < 4000  # a Python with torch imported, MiB
    assert read_result(job.out)["status"] == "error" and not is_finished(job.out)
    log = (tmp_path / "out" / "s" / "batch.log").read_text()
    assert "=== attempt 1" in log and "FAILED" in log


def _children(pid: int) -> list[int]:
    out = []
    for t in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{t}/children") as fh:
                out += [int(c) for c in fh.read().split()]
        except OSError:
            pass
    return out


@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="needs Linux /proc")
def test_killed_stage_process_raises_for_a_retry(tiny_scene, tmp_path):
    """SIGKILL of the stage process (as the OOM killer would) raises StageKilled, the exception
    Ray retries, and releases the scene's lock for the retry."""
    import signal
    import threading
    import time

    job = _job(tmp_path, tiny_scene, command="shape", overrides=["shape.iters=100000"])
    killed = []

    def kill_child() -> None:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            kids = [c for c in _children(os.getpid()) if "voxnero.batch.child" in
                    open(f"/proc/{c}/cmdline").read().replace("\0", " ")]
            if kids:
                time.sleep(0.5)
                os.kill(kids[0], signal.SIGKILL)
                killed.append(kids[0])
                return
            time.sleep(0.05)

    th = threading.Thread(target=kill_child, daemon=True)
    th.start()
    with pytest.raises(StageKilled, match="signal 9"):
        run_scene(job)
    th.join(5)
    assert killed and read_result(job.out) is None  # no row: Ray retries or reports it
    with _Lock(tmp_path / "out" / "s" / LOCK, 0.1):  # the retry can take the lock at once
        pass
