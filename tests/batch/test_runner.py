"""The batch driver: override routing, skipping without Ray, and two end-to-end runs on a local
Ray (2 CPUs): three tiny scenes plus a broken one, and a scene whose worker is killed mid-run.
"""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import threading
import time
from pathlib import Path

import pytest

from voxnero.batch.runner import exit_code, run_batch, split_overrides
from voxnero.batch.tasks import write_result
from voxnero.cli import main
from voxnero.errors import ConfigError


def _rows(out: Path) -> dict[str, dict]:
    with open(out / "results.csv", newline="") as fh:
        return {r["scene"]: r for r in csv.DictReader(fh)}


def test_split_overrides():
    g = split_overrides(["shape.iters=5", "batch.num_gpus=1", "material.iters=2",
                         "eval.voxel=0.02"])
    assert g == {"batch": ["batch.num_gpus=1"], "eval": ["eval.voxel=0.02"],
                 "stages": ["shape.iters=5", "material.iters=2"]}
    with pytest.raises(ConfigError, match="does not name its section"):
        split_overrides(["iters=5"])


def test_bad_override_fails_before_anything_runs(tmp_path):
    (tmp_path / "scenes" / "a").mkdir(parents=True)
    with pytest.raises(ConfigError, match="shape.no_such_key"):
        run_batch(tmp_path / "scenes", "standard", tmp_path / "out", ["shape.no_such_key=1"])
    assert main(["batch", str(tmp_path / "scenes"), "--out", str(tmp_path / "out"),
                 "batch.num_cpus=-1"]) == 2
    assert not (tmp_path / "out").exists()


def test_nothing_to_run_needs_no_ray(tmp_path):
    """Finished scenes are skipped and non-scenes reported before Ray would start."""
    import ray

    scenes = tmp_path / "scenes"
    (scenes / "done").mkdir(parents=True)
    (scenes / "junk").mkdir()
    (scenes / "junk" / "readme.txt").write_text("not a scene")
    write_result(tmp_path / "out" / "done", {"scene": "done", "status": "ok", "chamfer": 0.02})
    t0 = time.perf_counter()
    rows = run_batch(scenes, "standard", tmp_path / "out", progress=False, log=lambda s: None)
    assert time.perf_counter() - t0 < 10 and not ray.is_initialized()
    assert [(r["scene"], r["status"]) for r in rows] == [("done", "skipped"), ("junk", "error")]
    assert "no known scene format" in rows[1]["error"] and exit_code(rows) == 1
    got = _rows(tmp_path / "out")
    assert got["done"]["chamfer"] == "0.02" and got["junk"]["status"] == "error"
    assert exit_code(rows[:1]) == 0


def test_bad_per_scene_overrides_are_error_rows(tmp_path):
    """A manifest's per-scene override that names no section, an unknown key or a bad batch
    value fails that scene only, before Ray would start."""
    import ray

    scene = tmp_path / "scene"
    scene.mkdir()
    (scene / "transforms_train.json").write_text(json.dumps({"frames": []}))
    m = tmp_path / "m.yaml"
    m.write_text(f"- {{path: {scene}, name: nosec, overrides: [iters=5]}}\n"
                 f"- {{path: {scene}, name: unknown, overrides: [shape.no_such=1]}}\n"
                 f"- {{path: {scene}, name: badbatch, overrides: [batch.max_retries=-1]}}\n")
    rows = run_batch(m, "standard", tmp_path / "out", progress=False, log=lambda s: None)
    assert not ray.is_initialized()
    assert [r["status"] for r in rows] == ["error"] * 3
    assert "does not name its section" in rows[0]["error"]
    assert "shape.no_such" in rows[1]["error"]
    assert "batch.max_retries" in rows[2]["error"]
    assert all(r["error"].startswith("per-scene overrides: ") for r in rows)


@pytest.mark.slow
def test_three_scenes_and_a_broken_one(scene_copies, tiny_stages, tmp_path):
    """Local Ray, 2 CPUs: three results, one clear error, exit code 1; a re-run skips the
    finished scenes in seconds."""
    scenes = scene_copies(["s1", "s2", "s3"])
    broken = scenes / "broken"
    broken.mkdir()
    (broken / "transforms_train.json").write_text("{ this is not JSON")
    out = tmp_path / "out"
    argv = ["batch", str(scenes), "--preset", "standard", "--out", str(out), "--no-progress",
            *tiny_stages, "batch.local_cpus=2", "batch.num_cpus=0.5", "batch.dashboard=false"]
    t0 = time.perf_counter()
    assert main(argv) == 1
    t_first = time.perf_counter() - t0
    rows = _rows(out)
    assert sorted(rows) == ["broken", "s1", "s2", "s3"]
    for name in ("s1", "s2", "s3"):
        r = rows[name]
        assert r["status"] == "ok" and r["error"] == "" and r["attempts"] == "1"
        assert 0 < float(r["chamfer"]) < 1 and 0 < float(r["psnr"]) < 60
        assert 100 < float(r["peak_mem_mb"]) < 4000 and float(r["time_s"]) > 0
        for k in ("mesh", "model", "metrics"):
            assert Path(r[k]).is_file() and Path(r[k]).is_relative_to(out / name)
        assert json.loads((out / name / "result.json").read_text())["status"] == "ok"
    b = rows["broken"]
    assert b["status"] == "error" and "transforms_train.json" in b["error"]
    assert "unreadable pose file" in b["error"]
    md = (out / "results.md").read_text()
    assert "3 done now, 0 finished earlier (skipped), 1 failed" in md

    t0 = time.perf_counter()
    assert main(argv) == 1
    t_again = time.perf_counter() - t0
    again = _rows(out)
    assert [again[n]["status"] for n in ("s1", "s2", "s3")] == ["skipped"] * 3
    assert again["s1"]["chamfer"] == rows["s1"]["chamfer"] and again["broken"]["status"] == "error"
    print(f"first run {t_first:.1f} s, re-run {t_again:.1f} s")
    assert t_again < 5, f"re-run took {t_again:.1f} s (first run {t_first:.1f} s)"


@pytest.fixture
def local_ray():
    """A local Ray with the dashboard (it serves the state API ``ray.util.state``)."""
    import ray

    ray.init(num_cpus=2, include_dashboard=True, object_store_memory=100 * 1024 * 1024,
             log_to_driver=False)
    yield ray
    ray.shutdown()


def _last_step(log: Path) -> int:
    try:
        lines = log.read_text().splitlines()
    except OSError:
        return 0
    steps = [json.loads(ln).get("step", 0) for ln in lines if ln.strip().endswith("}")]
    return max(steps, default=0)


def _worker_pid(task_name: str) -> int | None:
    from ray.util.state import list_tasks, list_workers

    tasks = list_tasks(filters=[("name", "=", task_name), ("state", "=", "RUNNING")])
    if not tasks:
        return None
    if tasks[0].worker_pid:
        return int(tasks[0].worker_pid)
    workers = list_workers(filters=[("worker_id", "=", tasks[0].worker_id)])
    return int(workers[0].pid) if workers else None


@pytest.mark.slow
def test_killed_worker_resumes_from_checkpoint(local_ray, scene_copies, tiny_stages, tmp_path):
    """kill -9 of the worker running a scene: Ray retries the task, which resumes stage 1 from
    the checkpoint the stage process saved when its parent died (no periodic checkpoints)."""
    scenes = scene_copies(["k"])
    out = tmp_path / "out"
    log = out / "k" / "shape" / "log.jsonl"
    killed: dict = {}

    def killer() -> None:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and "pid" not in killed:
            step = _last_step(log)
            if step >= 20:
                try:
                    pid = _worker_pid("scene:k")
                except Exception:  # noqa: BLE001 - state API not ready yet
                    pid = None
                if pid:
                    killed.update(pid=pid, step=_last_step(log))
                    os.kill(pid, signal.SIGKILL)
                    return
            time.sleep(0.2)

    th = threading.Thread(target=killer, daemon=True)
    th.start()
    stages = [s for s in tiny_stages if s.startswith("shape.")]
    rc = main(["batch", str(scenes), "--preset", "standard", "--out", str(out), "--no-progress",
               *stages, "shape.iters=400", "shape.ckpt_every_s=1000", "batch.command=shape",
               "batch.eval=false"])
    th.join(timeout=5)
    assert "pid" in killed, "the scene finished before it could be killed"
    assert rc == 0
    row = _rows(out)["k"]
    assert row["status"] == "ok" and row["attempts"] == "2"
    text = (out / "k" / "batch.log").read_text()
    assert "=== attempt 2" in text
    resumed = [int(m) for m in re.findall(r"resumed from \S+ at step (\d+)", text)]
    assert len(resumed) == 1 and resumed[0] >= killed["step"] > 0
    steps = [json.loads(ln)["step"] for ln in log.read_text().splitlines()
             if '"loss"' in ln]
    assert steps == sorted(set(steps)), "stage 1 restarted from step 0"
    assert max(steps) == 400


@pytest.mark.slow
def test_address_joins_a_running_cluster(local_ray, scene_copies, tiny_stages, tmp_path):
    """``--address`` from another process joins the cluster (as with ``ray start --head``): the
    scene's task shows up in this cluster's state API."""
    import subprocess
    import sys

    from ray.util.state import list_tasks

    scenes = scene_copies(["j"])
    out = tmp_path / "out"
    address = local_ray.get_runtime_context().gcs_address
    stages = [s for s in tiny_stages if s.startswith("shape.")]
    proc = subprocess.run([sys.executable, "-m", "voxnero", "batch", str(scenes), "--out",
                           str(out), "--address", address, "--no-progress", *stages,
                           "batch.command=shape", "batch.eval=false"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Ray joined" in proc.stdout and "2 CPUs" in proc.stdout
    assert _rows(out)["j"]["status"] == "ok" and Path(_rows(out)["j"]["mesh"]).is_file()
    done = list_tasks(filters=[("name", "=", "scene:j")])
    assert [t.state for t in done] == ["FINISHED"]
