#!/usr/bin/env python
"""Benchmark one stage-1 training step, broken into phases.

Phases: ``sampling`` (coarse no-grad pass + importance samples), ``grid`` (SDF value + gradient
at all samples), ``neus`` (opacity + compositing), ``heads`` (feature grid + material MLP),
``shading`` (env lookups, split-sum, compositing on the background), ``loss`` and ``backward``
(including the optimiser step). Reports the median over steps of each phase, rays/s and
samples/s. Runs on an analytic sphere scene rendered in memory (no data needed) or on a scene
folder (``--scene``).

Example::

    python tools/bench_shape.py --res 96 --rays 4096 --coarse 32 --fine 16 --steps 10
    python tools/bench_shape.py --scene /work/shared/data/sphere_gold grid.normals=fd
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections import defaultdict
from types import SimpleNamespace

import torch


def _synthetic_scene(n_img: int = 8, size: int = 64):
    """A tiny in-memory scene: random colours, cameras on a ring (timing only)."""
    from voxnero.cameras.cameras import Cameras
    from voxnero.data.scene import Normalisation

    f = 0.5 * size / 0.36
    K = torch.tensor([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]]).expand(n_img, 3, 3)
    c2w = []
    for i in range(n_img):
        a = torch.tensor(2 * torch.pi * i / n_img)
        eye = torch.stack([3 * torch.cos(a), 3 * torch.sin(a), torch.tensor(0.5)])
        fwd = -eye / eye.norm()
        right = torch.linalg.cross(fwd, torch.tensor([0.0, 0.0, 1.0]))
        right = right / right.norm()
        down = torch.linalg.cross(fwd, right)
        m = torch.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, down, fwd, eye
        c2w.append(m)
    cams = Cameras(K.clone(), torch.stack(c2w), size, size)
    split = SimpleNamespace(images=torch.rand(n_img, size, size, 3), cameras=cams,
                            depth=None, masks=None)
    return SimpleNamespace(split=lambda name: split, splits={"train": split},
                           norm=Normalisation([0, 0, 0], 1.0), background="unknown", meta={})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--scene", default=None, help="scene folder (default: synthetic, in memory)")
    ap.add_argument("--preset", default="preview")
    ap.add_argument("--res", type=int, default=None, help="SDF grid resolution to time at")
    ap.add_argument("--steps", type=int, default=8)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--json", action="store_true", help="print one JSON line")
    ap.add_argument("overrides", nargs="*", help="shape config overrides key=value")
    a = ap.parse_args(argv)
    if a.threads:
        torch.set_num_threads(a.threads)
    from voxnero.config import resolve
    from voxnero.shape import losses
    from voxnero.shape.config import ShapeConfig
    from voxnero.shape.renderer import render_rays
    from voxnero.shape.trainer import ShapeTrainer

    cfg = resolve(ShapeConfig, "shape", a.preset, a.overrides)
    cfg.eval_every_s = 0
    if a.threads:
        cfg.threads = a.threads  # the trainer applies cfg.threads
    if a.scene:
        from voxnero.data.detect import load_scene

        scene = load_scene(a.scene)
    else:
        scene = _synthetic_scene()
    tr = ShapeTrainer(cfg, scene, "/tmp/voxnero_bench_shape", progress=False,
                      log=lambda s: None)
    tr.set_resolution(a.res or cfg.grid.res[-1])
    s = 100.0
    times: dict[str, list[float]] = defaultdict(list)
    n_samples = []
    for it in range(a.warmup + a.steps):
        t = [time.perf_counter()]
        phase: dict[str, float] = {}

        def mark(name: str, phase=phase, t=t) -> None:
            now = time.perf_counter()
            phase[name] = phase.get(name, 0.0) + now - t[0]
            t[0] = now

        cam, pix = torch.randint(0, tr.n_img, (cfg.sampling.rays,)), \
            torch.rand(cfg.sampling.rays, 2) * torch.tensor([tr.w, tr.h])
        from voxnero.cameras.rays import pixel_rays

        o, d = pixel_rays(tr.cams, cam, pix)
        tr.model.env.prepare()
        mark("shading")
        out = render_rays(tr.model, o, d, s, cfg, train=True, mark=mark)
        target = torch.rand_like(out["rgb"])
        loss = losses.color_loss(out["rgb"], target) + 0.1 * losses.eikonal(out["grad"])
        if cfg.loss.laplacian > 0:
            loss = loss + cfg.loss.laplacian * losses.laplacian(tr.model.sdf.grid[0],
                                                                tr.model.sdf.voxel)
        mark("loss")
        tr.opt.zero_grad()
        loss.backward()
        tr.opt.step()
        tr.model.env.release()
        mark("backward")
        if it >= a.warmup:
            for k, v in phase.items():
                times[k].append(v)
            times["total"].append(sum(phase.values()))
            n_samples.append(out["grad"].shape[0])
    med = {k: statistics.median(v) for k, v in times.items()}
    res = {"res": tr.model.sdf.res, "rays": cfg.sampling.rays,
           "samples_per_ray": cfg.sampling.coarse_keep + cfg.sampling.fine,
           "normals": cfg.grid.normals, "threads": torch.get_num_threads(),
           "ms": {k: round(1000 * v, 1) for k, v in med.items()},
           "rays_per_s": round(cfg.sampling.rays / med["total"]),
           "samples_per_s": round(statistics.median(n_samples) / med["total"])}
    if a.json:
        print(json.dumps(res))
    else:
        print(f"res {res['res']}^3, {res['rays']} rays, {res['samples_per_ray']} samples/ray, "
              f"normals {res['normals']}, {res['threads']} threads")
        for k, v in res["ms"].items():
            print(f"  {k:10s} {v:8.1f} ms")
        print(f"  rays/s {res['rays_per_s']}, samples/s {res['samples_per_s']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
