"""The choice of start of stage 1: a race of complete runs.

Where the SDF starts matters for mirrors (a mirror barely moves from where it starts), and where
the roughness starts matters for how a mirror's surface settles (docs/STAGE1.md, findings 10, 13
to 15). With ``grid.init_candidates`` or ``light.init_roughness_candidates`` the program trains
one complete run per start in ``starts/<name>/`` and keeps the one whose final model fits the
photos best (:func:`fit_psnr`). Each start is an ordinary
:class:`~voxnero.shape.trainer.ShapeTrainer` run with its own checkpoints: re-running the
command resumes the unfinished start and skips the finished ones.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from voxnero.shape import adaptive, losses, schedules
from voxnero.shape.config import ShapeConfig
from voxnero.shape.renderer import render_rays

if TYPE_CHECKING:
    from voxnero.shape.trainer import ShapeTrainer

FIT_SEED_OFFSET = 104729
"""Added to ``seed`` for the fixed training pixels of :func:`fit_psnr` (the same for every start,
independent of the training draws)."""


def has_race(cfg: ShapeConfig) -> bool:
    """Whether ``cfg`` asks for more than one start."""
    return bool(cfg.grid.init_candidates or cfg.light.init_roughness_candidates)


@torch.no_grad()
def fit_psnr(tr: ShapeTrainer, chunk: int = 8192) -> float:
    """PSNR (dB, linear RGB) of a trainer's current model on ``fit_rays`` training pixels drawn
    with a fixed seed (the same pixels for every start of a race), rendered as at test time."""
    gen = torch.Generator(device=tr.device).manual_seed(tr.cfg.seed + FIT_SEED_OFFSET)
    o, d, target = tr.pixel_batch(tr.cfg.fit_rays, gen)
    s = schedules.sharpness(tr.cfg, tr.step)
    tr.model.env.prepare()
    rgb = torch.cat([render_rays(tr.model, o[i:i + chunk], d[i:i + chunk], s, tr.cfg,
                                 train=False)["rgb"] for i in range(0, o.shape[0], chunk)])
    tr.model.env.release()
    return losses.psnr(rgb, target)


def race(tr: ShapeTrainer) -> Path:
    """Race the starts of ``tr``'s config (as given, ``tr.cfg_in``); ``tr`` becomes the winner.

    1. Initial radii, at ``light.init_roughness``: ``grid.init_radius`` first, then
       ``grid.init_candidates`` (folders ``r<radius>``); another radius must beat
       ``init_radius``'s fit by ``grid.init_margin`` dB to replace it.
    2. Initial roughness: each of ``light.init_roughness_candidates`` from the kept radius
       (folders ``r<radius>_rough<value>``); it replaces the kept start if it fits better.

    The kept start's ``mesh.ply``, ``sdf.npz``, ``envmap.exr`` and ``shape.json`` are copied to
    ``tr.outputs``, its log lines go to ``log.jsonl`` as they are and the other starts' with a
    ``trial`` field (the start's folder name), and the "init_radius" (and "init_roughness")
    decisions join its decisions. ``tr.train_time`` and ``tr.step`` become the race's totals,
    ``tr.model``, ``tr.sw`` and ``tr.cfg`` the kept start's.

    Returns:
        The kept mesh (input frame).
    """
    g, lc = tr.cfg_in.grid, tr.cfg_in.light
    radii = [g.init_radius] + [r for r in g.init_candidates if r != g.init_radius]
    roughs = [r for r in lc.init_roughness_candidates if r != lc.init_roughness]
    runs: list[tuple[str, float, ShapeTrainer | None]] = []  # (folder name, fit, trainer)
    seconds, steps = 0.0, 0

    def start(radius: float, rough: float | None, k: int, n: int) -> float:
        nonlocal seconds, steps
        name = f"r{radius:g}" if rough is None else f"r{radius:g}_rough{rough:g}"
        light = lc if rough is None else replace(lc, init_roughness=rough)
        sub = replace(tr.cfg_in, grid=replace(g, init_radius=radius, init_candidates=[]),
                      light=replace(light, init_roughness_candidates=[]))
        folder = tr.out / "starts" / name
        tr.log(f"[shape] start {name} ({k} of {n}): a complete run in {folder}")
        child = type(tr)(sub, tr.scene, folder, tr.device, tr.progress, tr.log)
        child.run()
        fit = fit_psnr(child)
        seconds += child.train_time
        steps += child.step
        tr.log(f"[shape] start {name}: final fit {fit:.2f} dB ({child.train_time:.0f} s)")
        runs.append((name, round(fit, 3), child))
        return fit

    def keep_only(best: int) -> None:  # free the losers' models as the race goes
        for i, (nm, ft, _) in enumerate(runs):
            if i != best:
                runs[i] = (nm, ft, None)

    n = len(radii) + len(roughs)
    best_k = 0
    for k, radius in enumerate(radii):
        fit = start(radius, None, k + 1, n)
        margin = g.init_margin if best_k == 0 else 0.0
        if k > 0 and fit > runs[best_k][1] + margin:
            best_k = k
        keep_only(best_k)
    k_radius = best_k
    decisions = [adaptive.Decision(
        "init_radius", radii[k_radius], [g.init_radius] + list(g.init_candidates),
        f"best fit of {len(radii)} complete runs to {tr.cfg.fit_rays} fixed training rays "
        f"(another start must beat r={g.init_radius:g} by {g.init_margin:g} dB): "
        + ", ".join(f"r={r:g}: {runs[i][1]:.2f} dB" for i, r in enumerate(radii)),
        {"radii": radii, "psnr": [runs[i][1] for i in range(len(radii))],
         "trial_steps": tr.cfg.iters}, tr.cfg.iters)]
    if roughs:
        for j, rough in enumerate(roughs):
            k = len(radii) + j
            fit = start(radii[k_radius], rough, k + 1, n)
            if fit > runs[best_k][1]:
                best_k = k
            keep_only(best_k)
        values = [lc.init_roughness] + roughs
        fits = [runs[k_radius][1]] + [runs[len(radii) + j][1] for j in range(len(roughs))]
        kept = lc.init_roughness if best_k < len(radii) else roughs[best_k - len(radii)]
        decisions.append(adaptive.Decision(
            "init_roughness", kept, values,
            f"best fit of {len(values)} complete runs from r={radii[k_radius]:g} "
            f"({tr.cfg.fit_rays} fixed training rays): "
            + ", ".join(f"{v:g}: {p:.2f} dB" for v, p in zip(values, fits, strict=True)),
            {"values": values, "psnr": fits, "radius": radii[k_radius]}, tr.cfg.iters))
    name, _, win = runs[best_k]
    assert win is not None
    tr.outputs.mkdir(parents=True, exist_ok=True)
    for fname in ("mesh.ply", "sdf.npz", "envmap.exr", "shape.json"):
        shutil.copyfile(win.out / fname, tr.outputs / fname)
    with open(tr.out / "log.jsonl", "w") as fh:
        for other, _, _ in runs:
            src = tr.out / "starts" / other / "log.jsonl"
            for line in src.read_text().splitlines():
                rec = json.loads(line)
                if other != name:
                    rec["trial"] = other
                fh.write(json.dumps(rec) + "\n")
    tr.model, tr.sw, tr.cfg = win.model, win.sw, win.cfg
    tr.step, tr.train_time = steps, seconds
    decisions[0].evidence["seconds"] = round(seconds, 2)
    tr.decisions = win.decisions + decisions
    for d in decisions:
        tr.log(d.line())
    tr.write_decisions()
    summary = json.loads((tr.outputs / "shape.json").read_text())
    summary.update(train_time_s=seconds, race_steps=steps, init_radius=radii[k_radius],
                   init_roughness=win.cfg.light.init_roughness)
    (tr.outputs / "shape.json").write_text(json.dumps(summary, indent=2))
    return tr.outputs / "mesh.ply"
