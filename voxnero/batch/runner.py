"""The batch driver: scenes in, one Ray task per scene, results out.

Without an address it starts a local Ray on this machine; with ``address`` it joins a running
cluster (``ray start --head`` on one node, ``ray start --address HEAD:6379`` on the others; the
scene folders and ``--out`` must be at the same path on every node, e.g. a shared filesystem).
Finished scenes (``result.json`` with ``status: ok``) are skipped before Ray is started, and so
are scenes that are visibly not scenes (missing folder, unknown format): these get an error row
at once. Nothing else is decided here: retries (``batch.max_retries``) belong to Ray.
"""

from __future__ import annotations

import logging
import os
import time
from pathlib import Path
from typing import Any

from voxnero.batch.config import BatchConfig
from voxnero.batch.manifest import SceneEntry, probe_scene, read_manifest
from voxnero.batch.results import all_succeeded, summarize, write_results
from voxnero.batch.tasks import SceneJob, read_result, remote_task, write_result
from voxnero.errors import ConfigError
from voxnero.safety.folder import RunFolder

STAGE_SECTIONS = ("shape", "material")


def split_overrides(items: list[str]) -> dict[str, list[str]]:
    """Sort ``key=value`` items by section: ``batch``, ``eval`` and ``stages``.

    ``batch.*`` configures the driver and tasks, ``eval.*`` goes to ``voxnero eval`` and
    ``shape.*`` / ``material.*`` to the stage commands.

    Raises:
        ConfigError: an item names no known section.
    """
    out: dict[str, list[str]] = {"batch": [], "eval": [], "stages": []}
    for item in items:
        head = item.split("=", 1)[0].strip().split(".")[0]
        if head in ("batch", "eval"):
            out[head].append(item)
        elif head in STAGE_SECTIONS:
            out["stages"].append(item)
        else:
            raise ConfigError(f"override {item!r} does not name its section",
                              fix=f"write shape.{item}, material.{item}, eval.{item} or "
                                  f"batch.{item}")
    return out


def check_stage_overrides(preset: str, stages: list[str], eval_items: list[str]) -> None:
    """Resolve the stage and eval configs once, so that a typo fails before any task runs.

    Raises:
        ConfigError: unknown key or bad value (the message names it).
    """
    from voxnero.config import resolve
    from voxnero.eval.config import EvalConfig
    from voxnero.material.config import MaterialConfig
    from voxnero.shape.config import ShapeConfig

    resolve(ShapeConfig, "shape", preset, [s for s in stages if s.startswith("shape.")],
            extra_sections=STAGE_SECTIONS)
    resolve(MaterialConfig, "material", preset,
            [s for s in stages if s.startswith("material.")], extra_sections=STAGE_SECTIONS)
    resolve(EvalConfig, "eval", preset, eval_items)


def _error_line(e: BaseException) -> str:
    """One line for a task's exception (Ray wraps the cause; keep its message only)."""
    cause = getattr(e, "cause", None)
    if isinstance(cause, BaseException):
        e = cause
    text = str(e).strip().splitlines()
    last = text[-1] if text else ""
    name = type(e).__name__
    if "Worker" in name or "NodeDied" in name or "ObjectLost" in name:
        return f"{name}: the worker running this scene died (retries exhausted); {last}"[:400]
    return f"{name}: {last}"[:400]


def _error_row(entry: SceneEntry, out: Path, error: str) -> dict[str, Any]:
    prev = read_result(out) or {}
    try:
        attempts = int((out / ".attempts").read_text())
    except (OSError, ValueError):
        attempts = int(prev.get("attempts") or 0)
    return {"scene": entry.name, "path": str(entry.path), "status": "error", "error": error,
            "time_s": None, "peak_mem_mb": None, "attempts": attempts, "out": str(out)}


def init_ray(cfg: BatchConfig, address: str | None) -> bool:
    """Connect to Ray (``address``) or start a local one; returns whether this call did it.

    An already initialised Ray (e.g. a test or a notebook that called ``ray.init``) is used as
    it is and left running.
    """
    import ray

    if ray.is_initialized():
        return False
    kw: dict[str, Any] = dict(log_to_driver=False, logging_level=logging.WARNING)
    if address:
        ray.init(address=address, **kw)
    else:
        ray.init(num_cpus=cfg.local_cpus or os.cpu_count(), include_dashboard=cfg.dashboard,
                 object_store_memory=cfg.object_store_mb * 1024 * 1024, **kw)
    return True


def run_batch(manifest: str | Path, preset: str, out: str | Path, overrides: list[str] = (),
              address: str | None = None, device: str = "auto", progress: bool = True,
              log=print) -> list[dict[str, Any]]:
    """Run every scene of ``manifest``; write ``results.csv``/``results.md``; return the rows.

    Args:
        manifest: folder of scene folders, a scene folder, or a YAML/CSV list
            (:mod:`voxnero.batch.manifest`).
        preset: preset name or YAML path (its ``batch:`` section sets the task resources).
        out: batch output folder; scene ``name`` writes into ``out/name/``.
        overrides: ``shape.``/``material.``/``eval.``/``batch.`` ``key=value`` items (a
            manifest's per-scene overrides come after them, ``batch.`` ones included).
        address: Ray cluster address (``HOST:6379`` or ``auto``); None starts a local Ray.
        device: passed to the stages (``auto``: CUDA when the task got a GPU from Ray).
        progress: show a progress bar over scenes.
        log: function for one-line messages.

    Returns:
        One row per scene, in manifest order (see :func:`voxnero.batch.tasks.run_scene`).

    Raises:
        ConfigError / DataError: the manifest or the overrides are wrong (nothing ran).
    """
    from voxnero.config import resolve

    out = Path(out).resolve()
    groups = split_overrides(list(overrides))
    cfg = resolve(BatchConfig, "batch", preset, groups["batch"])
    check_stage_overrides(preset, groups["stages"], groups["eval"])
    entries = read_manifest(manifest)
    preset_arg = str(Path(preset).resolve()) if Path(preset).suffix else preset

    with RunFolder(out, "batch", log=log):  # one batch per folder; scenes lock their own
        rows: dict[str, dict[str, Any]] = {}
        jobs: list[tuple[SceneEntry, BatchConfig, SceneJob]] = []
        for e in entries:
            sdir = out / e.name
            prev = read_result(sdir)
            if prev and prev.get("status") == "ok":
                rows[e.name] = {**prev, "status": "skipped"}
                continue
            err = probe_scene(e.path)
            if err is None:
                try:
                    g = split_overrides(e.overrides)
                    check_stage_overrides(preset, groups["stages"] + g["stages"],
                                          groups["eval"] + g["eval"])
                    cfg_e = resolve(BatchConfig, "batch", preset, groups["batch"] + g["batch"]) \
                        if g["batch"] else cfg
                except ConfigError as ce:
                    err = f"per-scene overrides: {' '.join(str(ce).split())}"
            if err is not None:
                row = _error_row(e, sdir, err)
                write_result(sdir, row)
                rows[e.name] = row
                continue
            jobs.append((e, cfg_e, SceneJob(name=e.name, scene=str(e.path), out=str(sdir),
                                            preset=preset_arg,
                                            overrides=groups["stages"] + g["stages"],
                                            eval_overrides=groups["eval"] + g["eval"],
                                            command=cfg_e.command, eval=cfg_e.eval, device=device,
                                            lock_timeout_s=cfg_e.lock_timeout_s)))
        n_skip = sum(r["status"] == "skipped" for r in rows.values())
        log(f"[batch] {len(entries)} scenes: {n_skip} finished earlier (skipped), "
            f"{len(rows) - n_skip} rejected (not a scene or bad overrides), {len(jobs)} to run")

        if jobs:
            _run_jobs(jobs, cfg, address, rows, len(entries), progress, log)
        ordered = [rows[e.name] for e in entries]
        csv_path, md_path = write_results(out, ordered)
        s = summarize(ordered)
        log(f"[batch] {s['ok']} done, {s['skipped']} skipped (finished earlier), "
            f"{s['error']} failed; wrote {csv_path} and {md_path}")
        return ordered


def _run_jobs(jobs: list[tuple[SceneEntry, BatchConfig, SceneJob]], cfg: BatchConfig,
              address: str | None,
              rows: dict[str, dict[str, Any]], total: int, progress: bool, log) -> None:
    import ray
    from tqdm import tqdm

    t0 = time.perf_counter()
    started = init_ray(cfg, address)
    how = "joined" if address else "started" if started else "in use"
    log(f"[batch] Ray {how} in {time.perf_counter() - t0:.1f} s: "
        f"{ray.cluster_resources().get('CPU', 0):.0f} CPUs, "
        f"{ray.cluster_resources().get('GPU', 0):.0f} GPUs; per scene {cfg.num_cpus:g} CPU, "
        f"{cfg.num_gpus:g} GPU, up to {cfg.max_retries} retries")
    try:
        refs = {}
        for e, c, job in jobs:  # c: the scene's batch config (per-scene batch.* overrides)
            task = remote_task(c.num_cpus, c.num_gpus, c.max_retries, c.memory_mb)
            refs[task.options(name=f"scene:{job.name}").remote(job)] = (e, job)
        pending = list(refs)
        bar = tqdm(total=total, initial=total - len(jobs), unit="scene", desc="batch",
                   disable=not progress, dynamic_ncols=True)
        n_err = sum(r["status"] == "error" for r in rows.values())
        while pending:
            ready, pending = ray.wait(pending, num_returns=1, timeout=1.0)
            for ref in ready:
                e, job = refs[ref]
                try:
                    row = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - one scene's failure is its row
                    row = _error_row(e, Path(job.out), _error_line(exc))
                    write_result(job.out, row)
                rows[e.name] = row
                if row["status"] == "error":
                    n_err += 1
                    bar.write(f"[batch] {e.name}: error: {row['error']}")
                bar.set_postfix(failed=n_err)
                bar.update(1)
        bar.close()
    finally:
        if started:
            ray.shutdown()


def exit_code(rows: list[dict[str, Any]]) -> int:
    """0 when every scene is finished, 1 otherwise."""
    return 0 if all_succeeded(rows) else 1
