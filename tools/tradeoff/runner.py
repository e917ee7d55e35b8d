"""Runs of a sweep: each training command and ``voxnero eval`` as its own measured child.

The child processes are :func:`voxnero.batch.process.run_timed`'s (launcher, own session, peak
RSS, timeout, process-group kill); the scores are :func:`voxnero.batch.tasks.scores` of
``voxnero eval``'s ``metrics.json``.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import socket
import sys
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from tools.tradeoff.points import REPO, Point, points_for_stage
from tools.tradeoff.report import (
    FIELDS,
    _cell,
    _num,
    is_done,
    merge_rows,
    read_csv,
    row_key,
    write_csv,
    write_outputs,
)
from voxnero.batch.process import ChildResult, kill_children, read_json, run_timed
from voxnero.batch.tasks import scores

__all__ = ["ChildResult", "Runner", "Task", "child_env", "kill_children", "plan", "run_child",
           "sweep"]


def child_env() -> dict[str, str]:
    """Environment of the children: one OpenMP / MKL thread, unbuffered output."""
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               PYTHONUNBUFFERED="1")
    return env


def run_child(cmd: Sequence[str], log: Path, timeout: float | None = None) -> ChildResult:
    """Run ``cmd`` from the repository with :func:`child_env`, stdout + stderr into ``log``.

    See :func:`voxnero.batch.process.run_timed`: peak RSS is ``ru_maxrss`` of the command (its
    launcher's ``os.wait4``), wall time is measured around it, and the command runs in its own
    session (killed on timeout, on Ctrl-C here and by :func:`kill_children`).

    Returns:
        exit code (``-signal`` if killed; 124 after ``timeout`` seconds), wall seconds, MiB.
    """
    return run_timed(cmd, log, timeout, env=child_env(), cwd=REPO)


def _voxnero(*args: str) -> list[str]:
    return [sys.executable, "-m", "voxnero", *args]


def _slug(text: str) -> str:
    h = hashlib.sha1(text.encode()).hexdigest()[:8]
    s = re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_")[:40]
    return f"{s}-{h}"



def _eval_metrics(metrics: dict) -> dict[str, float]:
    """Chamfer, mean normal error and novel-view PSNR from ``voxnero eval``'s metrics.json
    (NaN where absent)."""
    return {k: float("nan") if v is None else float(v) for k, v in scores(metrics).items()}


@dataclass
class Task:
    """One run of the sweep: a point on a scene in a stage, the ``repeat``-th time."""

    scene: Path
    point: Point
    stage: str
    repeat: int = 0

    def key(self) -> tuple[str, str, str, str, int]:
        """Identity of the run in the CSV (scene name, stage, preset, overrides, repeat)."""
        return (self.scene.name, self.stage, self.point.preset, " ".join(self.point.overrides),
                self.repeat)


class Runner:
    """Runs tasks: training command(s) then ``voxnero eval``; shares equal stage-1 runs."""

    def __init__(self, out: Path, jobs: int = 1, timeout: float | None = None,
                 log: Callable[[str], None] = print):
        self.out, self.jobs, self.timeout, self.log = out, jobs, timeout, log
        self._locks: dict[str, threading.Lock] = {}
        self._guard = threading.Lock()

    def _lock(self, key: str) -> threading.Lock:
        with self._guard:
            return self._locks.setdefault(key, threading.Lock())

    def shape_run(self, scene: Path, point: Point, repeat: int) -> tuple[Path, dict]:
        """The stage-1 run of (scene, preset, shape overrides, repeat): made once, then reused.

        Returns:
            run folder, ``{"rc", "wall_s", "peak_rss_mib", "train_s"}`` of its (first) making.
        """
        cfg = " ".join((point.preset, *point.for_stage("shape")))
        d = self.out / "runs" / scene.name / f"shape-{_slug(cfg)}" / f"r{repeat}"
        with self._lock(str(d)):
            done = read_json(d / "tradeoff_child.json")
            if done.get("rc") == 0 and (d / "mesh.ply").is_file():
                return d, done
            shutil.rmtree(d, ignore_errors=True)  # never resume half a run: it would skew time
            cmd = _voxnero("shape", str(scene), "--preset", point.preset, "--out", str(d),
                           "--no-eval", "--no-progress", "shape.threads=1",
                           *point.for_stage("shape"))
            res = run_child(cmd, d.parent / f"r{repeat}.shape.log", self.timeout)
            info = {"rc": res.rc, "wall_s": res.wall_s, "peak_rss_mib": res.peak_rss_mib,
                    "train_s": read_json(d / "shape.json").get("train_time_s", float("nan"))}
            if d.is_dir():
                (d / "tradeoff_child.json").write_text(json.dumps(info))
            return d, info

    def evaluate(self, target: Path, scene: Path) -> dict[str, float]:
        """``voxnero eval TARGET --scene SCENE --out TARGET/eval`` (reused if already there)."""
        metrics = target / "eval" / "metrics.json"
        if not metrics.is_file():
            res = run_child(_voxnero("eval", str(target), "--scene", str(scene), "--out",
                                     str(target / "eval")), target / "eval.log", self.timeout)
            if res.rc != 0:
                raise RuntimeError(f"voxnero eval failed (exit {res.rc}); see {target}/eval.log")
        return _eval_metrics(read_json(metrics))

    def run(self, task: Task) -> dict:
        """Run one task; returns its CSV row (``status`` "ok" or "failed: ...")."""
        p, scene = task.point, task.scene
        row = {k: "" for k in FIELDS}
        row.update(scene=scene.name, scene_path=str(scene), point=p.name, preset=p.preset,
                   overrides=" ".join(p.overrides), stage=task.stage, repeat=task.repeat,
                   jobs=self.jobs, load1=round(os.getloadavg()[0], 2),
                   started=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                   host=socket.gethostname())
        try:
            shape_repeat = 0 if task.stage == "material" else task.repeat
            sdir, s = self.shape_run(scene, p, shape_repeat)
            if s["rc"] != 0:
                raise RuntimeError(f"voxnero shape failed (exit {s['rc']}); see {sdir}.shape.log")
            row.update(shape_s=s["wall_s"], shape_train_s=s["train_s"])
            timed_rss = [s["peak_rss_mib"]] if task.stage != "material" else []
            target = sdir
            if task.stage in ("material", "both"):
                mdir = (self.out / "runs" / scene.name / f"material-{_slug(p.config)}"
                        / f"r{task.repeat}")
                shutil.rmtree(mdir, ignore_errors=True)
                cmd = _voxnero("material", str(sdir), "--scene", str(scene), "--preset",
                               p.preset, "--out", str(mdir), "--no-progress",
                               "material.threads=1", "material.eval_views=0",
                               *p.for_stage("material"))
                m = run_child(cmd, mdir.parent / f"r{task.repeat}.material.log", self.timeout)
                if m.rc != 0:
                    raise RuntimeError(f"voxnero material failed (exit {m.rc}); see "
                                       f"{mdir}.material.log")
                mj = read_json(mdir / "materials.json")
                row.update(material_s=m.wall_s,
                           material_train_s=(mj.get("times") or {}).get("train_s", ""))
                timed_rss.append(m.peak_rss_mib)
                target = mdir
            row["time_s"] = {"shape": row["shape_s"], "material": row["material_s"],
                             "both": (row["shape_s"] or 0) + (row["material_s"] or 0)
                             }[task.stage]
            row["peak_rss_mib"] = max(timed_rss)
            row.update(self.evaluate(target, scene))
            row["status"] = "ok"
        except RuntimeError as e:
            row["status"] = f"failed: {e}"
        return row


def plan(scenes: Sequence[Path], points: Sequence[Point], stage: str, repeats: int) -> list[Task]:
    """Every (scene, point, repeat) of a sweep, points in order, repeats innermost."""
    return [Task(sc, p, stage, k) for p in points_for_stage(points, stage) for sc in scenes
            for k in range(repeats)]


def sweep(tasks: Sequence[Task], out: Path, jobs: int = 1, timeout: float | None = None,
          run: Callable[[Task], dict] | None = None, log: Callable[[str], None] = print,
          note: str = "") -> list[dict]:
    """Run the tasks not yet in ``out/tradeoff.csv`` and rewrite the outputs after each.

    Args:
        tasks: runs to make; those whose key has an ``ok`` row in the CSV are skipped.
        out: output folder.
        jobs: runs at once.
        run: the function making one run (default :meth:`Runner.run`; tests pass a fake).

    Returns:
        all CSV rows afterwards.
    """
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "tradeoff.csv"
    rows = read_csv(csv_path)
    done = {row_key(r) for r in rows if is_done(r)}
    todo = [t for t in tasks if t.key() not in done]
    log(f"[tradeoff] {len(tasks)} runs, {len(tasks) - len(todo)} already in {csv_path}, "
        f"{len(todo)} to do ({jobs} at a time)")
    runner = run or Runner(out, min(jobs, max(1, len(todo))), timeout, log).run
    lock = threading.Lock()

    def _record(row: dict) -> None:
        nonlocal rows
        with lock:
            rows = merge_rows(rows, [row])
            write_csv(csv_path, rows)
        log(f"[tradeoff] {row['scene']} / {row['point']} / {row['stage']} #{row['repeat']}: "
            f"{row['status']}, time {_cell('time_s', _num(row['time_s']))} s, Chamfer "
            f"{_cell('chamfer', _num(row['chamfer']))}, PSNR {_cell('psnr', _num(row['psnr']))}")

    if jobs <= 1:
        for t in todo:
            _record(runner(t))
    else:
        pool = ThreadPoolExecutor(max_workers=jobs)
        try:
            for f in as_completed([pool.submit(runner, t) for t in todo]):
                _record(f.result())
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            kill_children()  # the workers' children would otherwise run on unobserved
            raise
        pool.shutdown()
    if rows:
        write_outputs(out, rows, note)
    return rows
