"""One scene's work as a Ray task: skip if finished, else run its stages and report a row.

:func:`run_scene` is a plain function (tests call it without Ray); :func:`remote_task` wraps it
as a Ray remote function with the scene's resources and retries. Layout of a scene's output
folder ``OUT/<name>/``:

* ``shape/`` (stage 1: mesh.ply, checkpoint.pt, log.jsonl), ``material/`` (stage 2, with
  ``batch.command: reconstruct``), ``eval/`` (metrics.json, scenes with ``gt/`` only);
* ``batch.log`` — everything the stages printed, one ``=== attempt k`` header per attempt (a
  retry shows ``[shape] resumed from ... at step N``);
* ``result.json`` — the scene's result row; ``status: ok`` marks the scene finished, and a
  re-run of the batch skips it.
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from voxnero.batch.process import read_json, wait_measured

RESULT = "result.json"
LOG = "batch.log"
LOCK = ".batch.lock"


class StageKilled(RuntimeError):
    """The scene's stage process was killed (signal, e.g. the OOM killer) or interrupted.

    Ray retries the task on this exception (``retry_exceptions``); the retry resumes from the
    scene's checkpoints.
    """


@dataclass
class SceneJob:
    """Everything one scene's task needs (plain data: it travels to any node).

    Attributes:
        name: scene name (output sub-folder).
        scene: scene folder, as seen from the node that runs the task (shared storage).
        out: the scene's output folder.
        preset: preset name or YAML path.
        overrides: ``shape.``/``material.`` overrides (command line, then the manifest's).
        eval_overrides: ``eval.`` overrides.
        command: ``reconstruct`` or ``shape``.
        eval: run ``voxnero eval`` when the scene has ``gt/``.
        device: ``auto``, ``cpu`` or ``cuda`` (``auto`` = CUDA when Ray gave the task a GPU).
        lock_timeout_s: how long to wait for a previous attempt's stage process to stop.
    """

    name: str
    scene: str
    out: str
    preset: str
    overrides: list[str] = field(default_factory=list)
    eval_overrides: list[str] = field(default_factory=list)
    command: str = "reconstruct"
    eval: bool = True
    device: str = "auto"
    lock_timeout_s: float = 600.0


def read_result(out: str | Path) -> dict[str, Any] | None:
    """The scene's ``result.json`` row, or None if absent, unreadable or empty."""
    return read_json(Path(out) / RESULT) or None


def is_finished(out: str | Path) -> bool:
    """Whether the scene in output folder ``out`` finished successfully (``status: ok``)."""
    r = read_result(out)
    return bool(r) and r.get("status") == "ok"


def write_result(out: str | Path, row: dict[str, Any]) -> Path:
    """Atomically write the scene's ``result.json``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / (RESULT + ".tmp")
    tmp.write_text(json.dumps(row, indent=1, default=str))
    os.replace(tmp, out / RESULT)
    return out / RESULT


def has_ground_truth(scene: str | Path) -> bool:
    """Whether the scene has evaluation data (a ``gt/`` folder)."""
    return (Path(scene) / "gt").is_dir()


def stage_commands(job: SceneJob) -> list[dict[str, Any]]:
    """The ``voxnero`` command lines of one scene, in order (``{"name", "argv"}`` items)."""
    out = Path(job.out)
    common = ["--preset", job.preset, "--device", job.device, "--no-progress"]
    if job.command == "reconstruct":
        stages = [{"name": "reconstruct",
                   "argv": ["reconstruct", job.scene, *common, "--out", str(out), *job.overrides]}]
    else:  # stage 1 only; its overrides may still carry the shape. prefix
        stages = [{"name": "shape",
                   "argv": ["shape", job.scene, *common, "--out", str(out / "shape"),
                            *job.overrides]}]
    if job.eval and has_ground_truth(job.scene):
        stages.append({"name": "eval",
                       "argv": ["eval", str(out / "shape"), "--scene", job.scene, "--preset",
                                job.preset, "--out", str(out / "eval"), *job.eval_overrides]})
    return stages



def scores(metrics: dict[str, Any]) -> dict[str, Any]:
    """Chamfer (``chamfer.cd``), mean normal error in degrees (``normals.mean_deg``) and
    novel-view PSNR in dB (``novel_view.psnr``) of a ``metrics.json``; None where absent."""

    def part(section: str, key: str) -> Any:
        d = metrics.get(section)
        return d.get(key) if isinstance(d, dict) else None

    return {"chamfer": part("chamfer", "cd"), "normal_deg": part("normals", "mean_deg"),
            "psnr": part("novel_view", "psnr")}


def collect_metrics(out: str | Path) -> dict[str, Any]:
    """Chamfer / normal error (``eval/metrics.json``), PSNR (``material/metrics.json``), paths.

    Missing files give None values (no ground truth, or stage 1 only).
    """
    out = Path(out)
    ev = scores(read_json(out / "eval" / "metrics.json"))
    mat = scores(read_json(out / "material" / "metrics.json"))

    def path_or_none(p: Path) -> str | None:
        return str(p) if p.exists() else None

    return {"chamfer": ev["chamfer"], "normal_deg": ev["normal_deg"], "psnr": mat["psnr"],
            "mesh": path_or_none(out / "shape" / "mesh.ply"),
            "model": path_or_none(out / "material" / "model.glb"),
            "metrics": path_or_none(out / "eval" / "metrics.json")}


class _Lock:
    """Exclusive ``flock`` on the scene's lock file; the stage process inherits it, so a retry
    waits until the previous attempt's stage process has stopped (and saved its checkpoint)."""

    def __init__(self, path: Path, timeout_s: float):
        self.path, self.timeout_s, self.fd = path, timeout_s, -1

    def __enter__(self) -> _Lock:
        self.fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        t0 = time.monotonic()
        while True:
            try:
                fcntl.flock(self.fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                return self
            except BlockingIOError:
                if time.monotonic() - t0 > self.timeout_s:
                    os.close(self.fd)
                    raise StageKilled(f"{self.path}: a previous attempt still runs after "
                                      f"{self.timeout_s:.0f} s") from None
                time.sleep(0.2)

    def __exit__(self, *exc) -> None:
        os.close(self.fd)


def _child_env(job: SceneJob) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONUNBUFFERED"] = "1"
    from voxnero.batch.child import PARENT_ENV

    env[PARENT_ENV] = str(os.getpid())
    if job.device == "auto" and not _ray_gpu_ids():
        env["CUDA_VISIBLE_DEVICES"] = ""  # no GPU reserved for this task: don't take one
    return env


def _ray_gpu_ids() -> list:
    try:
        import ray

        return list(ray.get_gpu_ids()) if ray.is_initialized() else []
    except Exception:  # noqa: BLE001 - outside a Ray worker
        return []


def run_scene(job: SceneJob) -> dict[str, Any]:
    """Run one scene's stages (skipping a finished scene) and return its result row.

    The row (also written to ``result.json``) has: ``scene``, ``path``, ``status`` (``ok``,
    ``skipped`` — finished by an earlier run — or ``error``), ``error`` (one line), ``time_s``
    (wall seconds of this attempt), ``peak_mem_mb`` (max RSS of the stage process, MiB),
    ``attempts``, ``stages`` (per-stage seconds), ``node``, the metrics and output paths of
    :func:`collect_metrics` and ``out``.

    Raises:
        StageKilled: the stage process died from a signal or was interrupted (Ray retries).
    """
    out = Path(job.out)
    out.mkdir(parents=True, exist_ok=True)
    prev = read_result(out)
    if prev and prev.get("status") == "ok":
        return {**prev, "status": "skipped"}
    with _Lock(out / LOCK, job.lock_timeout_s) as lock:
        attempts = int((prev or {}).get("attempts") or 0)
        att_file = out / ".attempts"
        try:
            attempts = max(attempts, int(att_file.read_text()))
        except (OSError, ValueError):
            pass
        attempts += 1
        att_file.write_text(str(attempts))
        stages = stage_commands(job)
        spec = out / ".batch_spec.json"
        status = out / ".batch_status.json"
        status.unlink(missing_ok=True)
        spec.write_text(json.dumps({"stages": stages, "status": str(status)}, indent=1))
        t0 = time.perf_counter()
        with open(out / LOG, "a") as log:
            log.write(f"=== attempt {attempts} on {socket.gethostname()} pid {os.getpid()} "
                      f"at {datetime.now(timezone.utc).isoformat(timespec='seconds')}\n")
            log.flush()
            proc = subprocess.Popen([sys.executable, "-m", "voxnero.batch.child", str(spec)],
                                    stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                    env=_child_env(job), pass_fds=(lock.fd,), cwd=str(out))
            rc, peak_mb = wait_measured(proc)
        dt = time.perf_counter() - t0
        done = read_json(status).get("stages", [])
        if rc < 0 or rc == 130:
            how = f"signal {-rc}" if rc < 0 else "an interrupt"
            raise StageKilled(f"scene {job.name}: stage process stopped by {how} after {dt:.0f} s "
                              f"(peak {peak_mb:.0f} MiB); the retry resumes from the checkpoint")
        failed = [s for s in done if s.get("rc")]
        if rc == 0:
            error = ""
        elif failed:
            error = f"{failed[0]['name']}: {failed[0]['error']}"
        else:
            error = f"stage process exit code {rc} (see {out / LOG})"
        row = {"scene": job.name, "path": job.scene, "status": "ok" if rc == 0 else "error",
               "error": error, "time_s": round(dt, 2), "peak_mem_mb": round(peak_mb, 1),
               "attempts": attempts,
               "stages": {s["name"]: s["time_s"] for s in done}, "node": socket.gethostname(),
               **collect_metrics(out), "out": str(out)}
        write_result(out, row)
        return row


def remote_task(num_cpus: float, num_gpus: float, max_retries: int, memory_mb: int = 0):
    """:func:`run_scene` as a Ray remote function with the scene's resources and retries.

    ``max_retries`` covers a dying worker (node lost, ``kill -9``) and :class:`StageKilled`.
    """
    import ray

    opts: dict[str, Any] = dict(num_cpus=num_cpus, num_gpus=num_gpus, max_retries=max_retries,
                                retry_exceptions=[StageKilled])
    if memory_mb > 0:
        opts["memory"] = int(memory_mb) * 1024 * 1024
    return ray.remote(**opts)(run_scene)


def job_dict(job: SceneJob) -> dict[str, Any]:
    """Plain-dict form of a job (for logs and tests)."""
    return asdict(job)
