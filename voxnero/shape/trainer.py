"""Stage-1 training loop: schedules, checkpoints with resume, progress, previews, logs, mesh.

Orchestration only; the physics lives in :mod:`voxnero.shape.renderer` and the losses in
:mod:`voxnero.shape.losses`. Outputs in the run folder:

* ``mesh.ply`` — marching cubes of the final SDF grid, cleaned, in the scene's **input frame**;
* ``checkpoint.pt`` — everything needed to resume (written periodically, after the step during
  which SIGINT/SIGTERM arrived, and at the end) and the run's fingerprint (scene and the settings
  that shape the model, :mod:`voxnero.safety.fingerprint`): re-running the same command resumes
  from it, bit-identically; another scene or other settings are refused (``--fresh``). NaN/Inf
  state is never saved, and a loss that stays non-finite stops the run
  (:mod:`voxnero.safety.guard`);
* ``log.jsonl`` — one JSON object per logged step: ``time`` (training seconds, excluding
  evaluation), ``step``, ``loss``, ``psnr``, ``s``, ``res`` and, for scenes with ground truth,
  ``chamfer`` entries (time-to-Chamfer curves);
* ``preview/`` — normal map and colour PNGs of a training view at intervals;
* ``config.yaml`` — the resolved config (written by the command); ``shape.json`` — decisions
  (switches) and summary;
* ``decisions.json`` — every adaptive decision with its setting, reason and evidence
  (:mod:`voxnero.shape.adaptive`), rewritten whenever one is taken;
* ``sdf.npz`` — the final SDF grid (unit frame) and ``envmap.exr`` — the learned env map
  (``mesh.ply``, ``sdf.npz``, ``envmap.exr`` and ``shape.json`` go to ``outputs``: the command
  stages them and moves them in when the run succeeded, :mod:`voxnero.safety.folder`);
* ``starts/r<radius>/`` (and ``starts/r<radius>_rough<value>/`` for
  ``light.init_roughness_candidates``) — with a race of starts, each start's complete run
  (same files); the kept one's mesh, grids, env map and summary are copied up, and
  ``log.jsonl`` holds every start's lines (the others' with a ``trial`` field naming the
  start's folder).
"""

from __future__ import annotations

import copy
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from voxnero.cameras.rays import image_rays, pixel_rays, random_pixels
from voxnero.config import to_dict
from voxnero.errors import RunFolderError
from voxnero.fields.grid import gaussian_blur3d, resample
from voxnero.fields.lights import IndirectNet, OcclusionNet
from voxnero.safety import fingerprint
from voxnero.safety.guard import NonFiniteGuard, check_finite, nonfinite
from voxnero.safety.stop import GracefulStop
from voxnero.shape import adaptive, losses
from voxnero.shape.config import ShapeConfig
from voxnero.shape.neus import sharpness_schedule
from voxnero.shape.occlusion import OcclusionTargets, trim_mesh
from voxnero.shape.renderer import ShapeModel, Switches, render_rays

CKPT = "checkpoint.pt"
STATE = ("checkpoint.pt", "checkpoint.tmp", "log.jsonl", "decisions.json", "preview", "starts")
"""Run state of a folder (``--fresh`` deletes it to start over; outputs are replaced when the
new run succeeds)."""
NONFINITE_FIX = ("lower the learning rates (optim.lr_sdf, optim.lr_env ...) or check the "
                 "scene's images and poses, then re-run with --fresh")


def resolve_switches(cfg: ShapeConfig, scene: Any,
                     decisions: list[adaptive.Decision] | None = None) -> Switches:
    """Decide the switches known before training (logged, written to ``decisions.json``).

    * background: :func:`voxnero.shape.adaptive.decide_background` (alpha or a constant image
      border → "alpha" with that colour, else "distant").
    * occlusion / indirect: "on" builds NeRO's full light model from the start, "off" never;
      "auto" starts **on** (until the grid has carved nobody can tell, and nets switched on late
      do not undo a neck that formed without them) and is decided during training from the
      self-occlusion of the carved surface (:meth:`ShapeTrainer.decide_occlusion`): dropped on
      a convex surface.
    * metallic: "auto" means on (a dielectric is metallic = 0 within the model).

    Args:
        cfg: stage-1 config.
        scene: the scene (``background``, ``meta``; train images for the border test).
        decisions: list to append the :class:`~voxnero.shape.adaptive.Decision` records to.
    """
    lc = cfg.light
    bg, color, dec = adaptive.decide_background(lc.background, scene)
    occ = adaptive.is_on(lc.occlusion)
    # the indirect light is mixed in by the occlusion probability: it needs the occlusion net
    ind = occ and adaptive.is_on(lc.indirect)
    if decisions is not None:
        decisions.append(dec)
        if adaptive.is_forced(lc.occlusion):
            why = f"forced by light.occlusion={lc.occlusion}"
        else:
            why = (f"auto: on until step {int(cfg.light.decide_at * cfg.iters)}, then "
                   "kept only if the carved surface sees itself")
        decisions.append(adaptive.Decision("occlusion", occ, lc.occlusion, why))
        decisions.append(adaptive.Decision(
            "indirect", ind, lc.indirect,
            "follows occlusion" if adaptive.is_on(lc.indirect) else "forced off"))
    return Switches(indirect=ind, occlusion=occ, metallic=adaptive.is_on(lc.metallic),
                    background=bg, bg_color=color)


def adapt_config(cfg: ShapeConfig, scene: Any,
                 decisions: list[adaptive.Decision] | None = None) -> ShapeConfig:
    """A copy of ``cfg`` with the grid resolutions and sample counts capped by the pixel
    footprint of the training cameras (``grid.res_auto``; the preset's values are upper bounds).
    """
    out = copy.deepcopy(cfg)
    try:
        cams = scene.split("train").cameras
        fp = adaptive.pixel_footprint(cams.K, cams.c2w)
    except Exception:  # no cameras to measure: keep the preset
        return out
    sc = cfg.sampling
    res, (c, f, k), dec = adaptive.adapt_resolution(cfg.grid.res, sc.coarse, sc.fine,
                                                    sc.coarse_keep, cfg.grid.bound, fp,
                                                    enabled=cfg.grid.res_auto)
    out.grid.res = res
    out.sampling.coarse, out.sampling.fine, out.sampling.coarse_keep = c, f, k
    if decisions is not None:
        decisions.append(dec)
    return out


class ShapeTrainer:
    """Train the stage-1 model on a scene's train split and write the run folder.

    Args:
        cfg: stage-1 config.
        scene: a :class:`voxnero.data.scene.Scene` with a "train" split (and optionally "test"
            with ``depth``/``masks`` for Chamfer logging).
        out: run folder.
        device: torch device.
        progress: show a tqdm bar.
        log: function for one-line messages.
        outputs: folder of the final outputs (default: ``out``); a command passes its run
            folder's staging folder, so that they appear only when the run succeeded.
    """

    def __init__(self, cfg: ShapeConfig, scene: Any, out: str | Path,
                 device: torch.device | str = "cpu", progress: bool = True,
                 log: Callable[[str], None] = print, outputs: str | Path | None = None):
        self.cfg = cfg
        self.scene = scene
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.outputs = self.out if outputs is None else Path(outputs)
        self.device = torch.device(device)
        self.progress = progress
        self.log = log
        if cfg.threads > 0:
            torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        self.gen = torch.Generator(device=self.device).manual_seed(cfg.seed)
        train = scene.split("train")
        self.cams = train.cameras.to(self.device) if hasattr(train.cameras, "to") \
            else train.cameras
        self.n_img, self.h, self.w = train.images.shape[0], train.images.shape[1], \
            train.images.shape[2]
        self.images = torch.as_tensor(train.images, dtype=torch.float32).reshape(-1, 3) \
            .to(self.device)
        self.decisions: list[adaptive.Decision] = []
        self.cfg_in = cfg
        """The config as given (before :func:`adapt_config`): each start of a race gets it."""
        self.cfg = cfg = adapt_config(cfg, scene, self.decisions)
        self.sw = resolve_switches(cfg, scene, self.decisions)
        self.occ_pending = cfg.light.occlusion == "auto"
        """An "auto" occlusion not yet measured on (re-measured until ``decide_until``)."""
        self.fingerprint = fingerprint.make(cfg, scene=fingerprint.scene_digest(scene))
        """Scene and model-shaping settings, saved in the checkpoint and checked on resume."""
        self.guard = NonFiniteGuard("shape", self._nonfinite_cause, NONFINITE_FIX)
        self.model = ShapeModel(cfg, self.sw).to(self.device)
        self.coarse_voxel = self.model.sdf.voxel
        """Voxel of the first grid: smoothing lengths are fixed in space across resolutions."""
        self.opt = self._optimizer()
        self.step = 0
        self.train_time = 0.0
        self.occ_targets: OcclusionTargets | None = None
        self.eval_split = None
        if "test" in getattr(scene, "splits", {}):
            te = scene.split("test")
            if te.depth is not None and te.masks is not None:
                self.eval_split = te
        self._last_eval = 0.0

    def _optimizer(self) -> torch.optim.Adam:
        """Adam over the model's parameter groups (one per learning rate)."""
        return torch.optim.Adam(self.model.param_groups(self.cfg), betas=(0.9, 0.99), eps=1e-15)

    # ------------------------------------------------------------------ schedules
    def res_at(self, step: int) -> int:
        """SDF grid resolution scheduled for ``step``."""
        g = self.cfg.grid
        k = sum(1 for f in g.upsample_at if step >= int(f * self.cfg.iters))
        return g.res[k]

    def sharpness(self, step: int) -> float:
        """NeuS sharpness scheduled for ``step``."""
        n = self.cfg.neus
        return sharpness_schedule(step / max(self.cfg.iters * n.ramp, 1), n.s_start, n.s_end)

    def lr_factor(self, step: int) -> float:
        """Warm-up then cosine decay to ``optim.decay``."""
        o = self.cfg.optim
        warm = min(1.0, (step + 1) / max(o.warmup, 1))
        f = min(step / max(self.cfg.iters, 1), 1.0)
        return warm * (o.decay + (1 - o.decay) * 0.5 * (1 + math.cos(math.pi * f)))

    # ------------------------------------------------------------------ grid resolution
    def set_resolution(self, res: int) -> None:
        """Resample the SDF grid to ``res`` and reset its optimiser state."""
        old = self.model.sdf.grid
        if old.shape[-1] == res:
            return
        self.model.sdf.upsample(res)
        for group in self.opt.param_groups:
            if group.get("name") == "sdf":
                self.opt.state.pop(old, None)
                group["params"] = [self.model.sdf.grid]
                if self.cfg.optim.lr_sdf_per_voxel:
                    # Adam moves every voxel by ~lr per step whatever its gradient: keep the
                    # step a fixed fraction of the voxel so that the bumps it leaves (slope ≈
                    # step / voxel) do not grow when the voxels shrink
                    base = group.get("base_lr", group["lr"])
                    group["base_lr"] = base * old.shape[-1] / res
                    group["lr"] = group["lr"] * old.shape[-1] / res
        self.log(f"[shape] step {self.step}: SDF grid {old.shape[-1]}^3 -> {res}^3")

    # ------------------------------------------------------------------ checkpoints
    def save_checkpoint(self) -> Path:
        """Atomically write ``checkpoint.pt`` (with the run's fingerprint).

        Raises:
            TrainingError: the model or the optimiser state holds NaN/Inf (nothing written).
            RunFolderError: the run folder was removed.
        """
        path = self.out / CKPT
        check_finite(self._state_tensors(), path, NONFINITE_FIX)
        if not self.out.is_dir():
            raise RunFolderError("the run folder was removed during the run", path=self.out,
                                 fix="re-run the command (into this --out it starts over)")
        tmp = path.with_suffix(".tmp")
        torch.save({"fingerprint": self.fingerprint,
                    "model": self.model.state_dict(), "opt": self.opt.state_dict(),
                    "step": self.step, "train_time": self.train_time,
                    "res": self.model.sdf.res, "gen": self.gen.get_state(),
                    "config": to_dict(self.cfg), "switches": asdict(self.sw),
                    "decisions": [asdict(d) for d in self.decisions],
                    "occ_pending": self.occ_pending}, tmp)
        os.replace(tmp, path)
        return path

    def load_checkpoint(self) -> bool:
        """Resume from ``checkpoint.pt`` if present; returns whether it did."""
        path = self.out / CKPT
        if not path.is_file():
            return False
        ck = torch.load(path, map_location=self.device, weights_only=False)
        if not fingerprint.check_resume(ck.get("fingerprint"), self.fingerprint, path, "shape"):
            self.log(f"[shape] note: {path} predates run fingerprints; resuming without "
                     "checking its scene and settings")
        self.set_resolution(int(ck["res"]))
        sw = ck.get("switches", {})
        if sw.get("occlusion") and self.model.occlusion is None:  # switched on by "auto"
            self.enable_light_nets(bool(sw.get("indirect")), add_to_optimizer=False)
        elif not sw.get("occlusion", True) and self.model.occlusion is not None:  # dropped
            self.disable_light_nets(remove_from_optimizer=False)
        if "decisions" in ck:
            self.decisions = [adaptive.Decision(**d) for d in ck["decisions"]]
            self.occ_pending = bool(ck.get("occ_pending", False))
        self.model.load_state_dict(ck["model"])
        self.opt = self._optimizer()
        self.opt.load_state_dict(ck["opt"])
        self.step = int(ck["step"])
        self.train_time = float(ck["train_time"])
        self.gen.set_state(ck["gen"])
        self._last_eval = self.train_time
        self.log(f"[shape] resumed from {path} at step {self.step} "
                 f"({self.train_time:.0f} s trained)")
        return True

    # ------------------------------------------------------------------ one step
    def pixel_batch(self, n: int, gen: torch.Generator
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``n`` random training pixels drawn with ``gen``: ray origins and directions
        ``(n, 3)`` (unit frame) and the photos' linear RGB ``(n, 3)`` there."""
        cam, pix = random_pixels(n, self.n_img, self.h, self.w, generator=gen,
                                 device=self.device)
        pi = pix.long()
        target = self.images[(cam * self.h + pi[:, 1]) * self.w + pi[:, 0]]
        o, d = pixel_rays(self.cams, cam, pix)
        return o, d, target

    def train_step(self) -> dict[str, float]:
        """One optimisation step; returns scalars for logging."""
        cfg = self.cfg
        res = self.res_at(self.step)
        if res != self.model.sdf.res:
            self.set_resolution(res)
        s = self.sharpness(self.step)
        lrf = self.lr_factor(self.step)
        for g in self.opt.param_groups:
            g["lr"] = g.setdefault("base_lr", g["lr"]) * lrf
        self.maybe_decide_occlusion()
        o, d, target = self.pixel_batch(cfg.sampling.rays, self.gen)
        m = self.model
        m.env.prepare()
        out = render_rays(m, o, d, s, cfg, train=True, generator=self.gen)
        lc = cfg.loss
        l_col = losses.color_loss(out["rgb"], target, lc.charbonnier_eps, lc.color_space)
        l_eik = losses.eikonal(out["grad"])
        l_lap = losses.laplacian(m.sdf.grid[0], m.sdf.voxel) if lc.laplacian > 0 else 0.0
        loss = l_col + lc.eikonal * l_eik + lc.laplacian * l_lap
        l_ns = torch.zeros(())
        if lc.normal_smooth > 0 and "x" in out and \
                self.step >= int(lc.normal_smooth_start * cfg.iters):
            keep = out["acc_hit"] > 0.5
            x = out["x"][keep]
            jit = torch.randn(x.shape, generator=self.gen, device=x.device)
            xj = x + jit * (lc.normal_smooth_radius * self.coarse_voxel)
            _, g2 = m.sdf.sdf_grad(torch.cat([x, xj]), cfg.grid.normals, cfg.grid.fd_step)
            g2 = torch.nn.functional.normalize(g2, dim=-1)
            l_ns = losses.normal_smoothness(g2[:x.shape[0]], g2[x.shape[0]:])
            loss = loss + lc.normal_smooth * l_ns
        l_occ = torch.zeros(())
        if "occ" in out and self.step >= int(lc.occlusion_start * cfg.iters):
            if self.occ_targets is None or self.step % lc.occlusion_every == 0:
                self.occ_targets = self._build_occlusion()
            if self.occ_targets is not None:
                keep = out["acc_hit"] > 0.5
                tgt, valid = self.occ_targets.test(out["x"][keep], out["n_hit"][keep],
                                                   out["refl"][keep])
                if bool(valid.any()):  # only reflected rays that leave the surface (d·n > 0)
                    l_occ = losses.occlusion_loss(out["occ"][keep][valid], tgt[valid])
                    loss = loss + lc.occlusion * l_occ
        self.opt.zero_grad(set_to_none=True)
        if not torch.isfinite(loss):
            # never let one bad batch poison the grids (Adam would spread the NaN everywhere)
            m.env.release()
            self.log(f"[shape] step {self.step}: non-finite loss, step skipped")
            return {"loss": float("nan"), "color": float("nan"), "eik": float("nan"),
                    "occ": 0.0, "nsmooth": 0.0, "psnr": 0.0, "s": s, "res": m.sdf.res}
        loss.backward()
        g = m.sdf.grid
        if cfg.grid.grad_smooth > 0 and g.grad is not None:
            g.grad[0] = gaussian_blur3d(g.grad[0], cfg.grid.grad_smooth)
        if not all(torch.isfinite(p.grad).all() for p in m.parameters() if p.grad is not None):
            # a finite loss can still give a NaN gradient (0 * inf in a saturated exp): skip
            self.opt.zero_grad(set_to_none=True)
            m.env.release()
            self.log(f"[shape] step {self.step}: non-finite gradient, step skipped")
            return {"loss": float("nan"), "color": float("nan"), "eik": float("nan"),
                    "occ": 0.0, "nsmooth": 0.0, "psnr": 0.0, "s": s, "res": m.sdf.res}
        self.opt.step()
        m.env.release()
        return {"loss": float(loss.detach()), "color": float(l_col.detach()),
                "eik": float(l_eik.detach()), "occ": float(l_occ.detach()),
                "nsmooth": float(l_ns.detach()),
                "psnr": losses.psnr(out["rgb"], target), "s": s, "res": m.sdf.res}

    def _timed_step(self, bar) -> dict[str, float]:
        """:meth:`train_step`, then advance the step, the training clock and the bar."""
        t0 = time.perf_counter()
        rec = self.train_step()
        self.guard.update(math.isfinite(rec["loss"]), self.step,
                          last=self.step + 1 >= self.cfg.iters)
        self.step += 1
        self.train_time += time.perf_counter() - t0
        bar.update(1)
        return rec

    def _state_tensors(self) -> list[tuple[str, torch.Tensor]]:
        """Parameters and optimiser moments, named (what a checkpoint saves)."""
        named = list(self.model.state_dict().items())
        for i, st in enumerate(self.opt.state.values()):
            named += [(f"optimiser state {i}.{k}", v) for k, v in st.items()
                      if isinstance(v, torch.Tensor)]
        return named

    def _nonfinite_cause(self) -> str:
        """The likely cause of a loss that stays non-finite, checked in the order of the data
        flow: photos, cameras, model state, else the settings."""
        if not bool(torch.isfinite(self.images).all()):
            return "the training images hold NaN/Inf pixels (check the scene's image files)"
        cams = [(n, getattr(self.cams, n)) for n in ("K", "c2w")
                if isinstance(getattr(self.cams, n, None), torch.Tensor)]
        if nonfinite(cams):
            return "the camera poses or intrinsics hold NaN/Inf (check the scene's pose file)"
        bad = nonfinite(self.model.named_parameters())
        if bad:
            return (f"the model's {', '.join(bad[:3])} became NaN/Inf: learning rates too high "
                    "(optim.lr_*) for this scene")
        o = self.cfg.optim
        return (f"the settings (learning rates optim.lr_sdf={o.lr_sdf:g}, "
                f"optim.lr_env={o.lr_env:g}; loss weights; sampling.rays="
                f"{self.cfg.sampling.rays}) or a degenerate scene (no pixel sees the object)")

    # ------------------------------------------------------------------ race of starts
    def race_starts(self) -> Path:
        """Race of starts. Each start is a complete run in
        ``starts/<name>/`` with its own checkpoints (re-running resumes the unfinished one and
        skips the finished ones), judged on its final fit to the photos (:meth:`fit_psnr`).

        1. Initial radii, at ``light.init_roughness``: ``grid.init_radius`` first, then
           ``grid.init_candidates`` (folders ``r<radius>``); another radius must beat
           ``init_radius``'s fit by ``grid.init_margin`` dB to replace it.
        2. Initial roughness: each of ``light.init_roughness_candidates`` from the kept radius
           (folders ``r<radius>_rough<value>``); it replaces the kept start if it fits better.

        The kept start's ``mesh.ply``, ``sdf.npz``, ``envmap.exr`` and ``shape.json`` are copied
        here, its log lines go to ``log.jsonl`` as they are and the other starts' with a
        ``trial`` field (the start's folder name), and the "init_radius" (and "init_roughness")
        decisions join its decisions. ``train_time`` and ``step`` become the race's totals.
        Returns the kept mesh (input frame)."""
        import shutil

        g, lc = self.cfg_in.grid, self.cfg_in.light
        radii = [g.init_radius] + [r for r in g.init_candidates if r != g.init_radius]
        roughs = [r for r in lc.init_roughness_candidates if r != lc.init_roughness]
        runs: list[tuple[str, float, ShapeTrainer | None]] = []  # (folder name, fit, trainer)
        seconds, steps = 0.0, 0

        def start(radius: float, rough: float | None, k: int, n: int) -> float:
            nonlocal seconds, steps
            name = f"r{radius:g}" if rough is None else f"r{radius:g}_rough{rough:g}"
            light = lc if rough is None else replace(lc, init_roughness=rough)
            sub = replace(self.cfg_in, grid=replace(g, init_radius=radius, init_candidates=[]),
                          light=replace(light, init_roughness_candidates=[]))
            folder = self.out / "starts" / name
            self.log(f"[shape] start {name} ({k} of {n}): a complete run in {folder}")
            tr = ShapeTrainer(sub, self.scene, folder, self.device, self.progress, self.log)
            tr.run()
            fit = tr.fit_psnr()
            seconds += tr.train_time
            steps += tr.step
            self.log(f"[shape] start {name}: final fit {fit:.2f} dB ({tr.train_time:.0f} s)")
            runs.append((name, round(fit, 3), tr))
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
            f"best fit of {len(radii)} complete runs to {self.cfg.fit_rays} fixed training rays "
            f"(another start must beat r={g.init_radius:g} by {g.init_margin:g} dB): "
            + ", ".join(f"r={r:g}: {runs[i][1]:.2f} dB" for i, r in enumerate(radii)),
            {"radii": radii, "psnr": [runs[i][1] for i in range(len(radii))],
             "trial_steps": self.cfg.iters}, self.cfg.iters)]
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
                f"({self.cfg.fit_rays} fixed training rays): "
                + ", ".join(f"{v:g}: {p:.2f} dB" for v, p in zip(values, fits, strict=True)),
                {"values": values, "psnr": fits, "radius": radii[k_radius]}, self.cfg.iters))
        name, _, win = runs[best_k]
        assert win is not None
        self.outputs.mkdir(parents=True, exist_ok=True)
        for fname in ("mesh.ply", "sdf.npz", "envmap.exr", "shape.json"):
            shutil.copyfile(win.out / fname, self.outputs / fname)
        with open(self.out / "log.jsonl", "w") as fh:
            for other, _, _ in runs:
                src = self.out / "starts" / other / "log.jsonl"
                for line in src.read_text().splitlines():
                    rec = json.loads(line)
                    if other != name:
                        rec["trial"] = other
                    fh.write(json.dumps(rec) + "\n")
        self.model, self.sw, self.cfg = win.model, win.sw, win.cfg
        self.step, self.train_time = steps, seconds
        decisions[0].evidence["seconds"] = round(seconds, 2)
        self.decisions = win.decisions + decisions
        for d in decisions:
            self.log(d.line())
        self.write_decisions()
        summary = json.loads((self.outputs / "shape.json").read_text())
        summary.update(train_time_s=seconds, race_steps=steps, init_radius=radii[k_radius],
                       init_roughness=win.cfg.light.init_roughness)
        (self.outputs / "shape.json").write_text(json.dumps(summary, indent=2))
        return self.outputs / "mesh.ply"

    @torch.no_grad()
    def fit_psnr(self, chunk: int = 8192) -> float:
        """PSNR (dB, linear RGB) of the current model on ``fit_rays`` training pixels drawn
        with a fixed seed (the same pixels for every start of a race), rendered as at test
        time."""
        gen = torch.Generator(device=self.device).manual_seed(self.cfg.seed + 104729)
        o, d, target = self.pixel_batch(self.cfg.fit_rays, gen)
        s = self.sharpness(self.step)
        self.model.env.prepare()
        rgb = torch.cat([render_rays(self.model, o[i:i + chunk], d[i:i + chunk], s, self.cfg,
                                     train=False)["rgb"] for i in range(0, o.shape[0], chunk)])
        self.model.env.release()
        return losses.psnr(rgb, target)

    # ------------------------------------------------------------------ surfaces
    @torch.no_grad()
    def extract(self, res: int | None = None, clean: bool = True):
        """Marching cubes of the current SDF grid (resampled to ``res``), unit frame."""
        from voxnero.mesh.cleanup import clean_mesh
        from voxnero.mesh.extract import extract_mesh

        g = self.model.sdf.grid.data
        if res and res != g.shape[-1]:
            g = resample(g, res)
        mesh = extract_mesh(g[0].cpu(), self.model.sdf.bounds.cpu())
        return clean_mesh(mesh) if clean else mesh

    def _build_occlusion(self) -> OcclusionTargets | None:
        try:
            mesh = self.extract(None, clean=False)
        except Exception as e:  # empty surface early on: no targets this time
            self.log(f"[shape] occlusion targets skipped: {e}")
            return None
        lc = self.cfg.light
        mesh = trim_mesh(mesh, self.cfg.sampling.radius)
        if len(mesh.triangles) == 0:
            return None
        return OcclusionTargets(mesh, offset=lc.occlusion_offset, t_near=lc.occlusion_t_near,
                                smooth=lc.occlusion_smooth)

    # ------------------------------------------------------------------ adaptive light model
    def enable_light_nets(self, indirect: bool, add_to_optimizer: bool = True) -> None:
        """Create the occlusion (and indirect) nets now and give them to the optimiser."""
        cfg, m = self.cfg, self.model
        new = []
        if m.occlusion is None:
            m.occlusion = OcclusionNet(cfg.grid.feat_dim, cfg.light.hidden).to(self.device)
            new += list(m.occlusion.parameters())
        if indirect and m.indirect is None:
            m.indirect = IndirectNet(cfg.grid.feat_dim, cfg.light.hidden).to(self.device)
            new += list(m.indirect.parameters())
        self.sw.occlusion, self.sw.indirect = True, m.indirect is not None
        if add_to_optimizer and new:
            self.opt.add_param_group(dict(name="light", params=new, lr=cfg.optim.lr_light))

    def disable_light_nets(self, remove_from_optimizer: bool = True) -> None:
        """Drop the occlusion and indirect nets (and their optimiser group): direct light only."""
        m = self.model
        m.occlusion, m.indirect = None, None
        self.sw.occlusion, self.sw.indirect = False, False
        self.occ_targets = None
        if remove_from_optimizer:
            keep = [g for g in self.opt.param_groups if g.get("name") != "light"]
            for g in self.opt.param_groups:
                if g.get("name") == "light":
                    for q in g["params"]:
                        self.opt.state.pop(q, None)
            self.opt.param_groups[:] = keep

    def view_rays(self, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``n`` random training-camera rays (own RNG: the training draws are unchanged)."""
        gen = torch.Generator(device=self.device).manual_seed(self.cfg.seed + 7919)
        o, d, _ = self.pixel_batch(n, gen)
        return o, d

    def maybe_decide_occlusion(self) -> None:
        """For ``light.occlusion=auto`` (the nets are on from the start): at
        ``light.decide_at`` measure the self-occlusion of the carved surface; keep the
        occlusion/indirect model if it is above ``light.self_occlusion_min``, else drop it and
        measure again every ``loss.occlusion_every`` steps until ``light.decide_until``,
        switching fresh nets on if it rises above (then they stay on)."""
        cfg = self.cfg
        start = int(cfg.light.decide_at * cfg.iters)
        if not self.occ_pending or self.step < start:
            return
        if self.step > int(cfg.light.decide_until * cfg.iters):
            self.occ_pending = False
            return
        if (self.step - start) % max(cfg.loss.occlusion_every, 1):
            return
        self.decide_occlusion()

    def decide_occlusion(self) -> bool:
        """Measure the self-occlusion now, record the decision; returns whether it is on."""
        lc = self.cfg.light
        t0 = time.perf_counter()
        try:
            mesh = self.extract(None, clean=False)
        except Exception as e:  # nothing carved yet: measure again later
            self.log(f"[shape] self-occlusion not measured at step {self.step}: {e}")
            return False
        o, d = self.view_rays(lc.decide_rays)
        ev = adaptive.measure_self_occlusion(mesh, o, d, smooth=lc.occlusion_smooth,
                                             radius=self.cfg.sampling.radius)
        on, why = adaptive.decide_self_occlusion(ev["reflected_hit_fraction"],
                                                 ev["reflected_rays"], lc.self_occlusion_min)
        ev["grid_res"] = self.model.sdf.res
        ev["seconds"] = round(time.perf_counter() - t0, 3)
        ind = on and adaptive.is_on(lc.indirect)
        for name, val, setting in (("occlusion", on, lc.occlusion),
                                   ("indirect", ind, lc.indirect)):
            dec = adaptive.Decision(name, val, setting, why if name == "occlusion" else
                                    ("follows occlusion" if adaptive.is_on(lc.indirect)
                                     else "forced off"), ev, self.step)
            self.decisions.append(dec)
        self.log(self.decisions[-2].line())
        if on:
            self.enable_light_nets(ind)
            self.occ_pending = False
        elif self.model.occlusion is not None:
            self.disable_light_nets()
        self.write_decisions()
        return on

    def write_decisions(self) -> Path:
        """Write ``decisions.json`` in the run folder."""
        return adaptive.write_decisions(self.out / "decisions.json", self.decisions)

    def evaluate(self) -> dict[str, float] | None:
        """Chamfer of the current mesh at the test views (scenes with GT), input frame."""
        if self.eval_split is None:
            return None
        from voxnero.eval.chamfer import chamfer_at_views

        te = self.eval_split
        try:
            mesh = self.extract(self.cfg.eval_mesh_res or None)
        except Exception as e:
            self.log(f"[shape] evaluation skipped: {e}")
            return None
        r = chamfer_at_views(mesh, te.cameras, te.depth, te.masks, norm=self.scene.norm)
        return {k: float(v) for k, v in r.items()}

    # ------------------------------------------------------------------ previews
    @torch.no_grad()
    def render_image(self, index: int = 0, downscale: int = 2, chunk: int = 8192
                     ) -> dict[str, torch.Tensor]:
        """Render a train view: ``rgb (H', W', 3)`` linear and ``normal (H', W', 3)``."""
        o, d = image_rays(self.cams, index, downscale)
        hh, ww = o.shape[:2]
        o, d = o.reshape(-1, 3), d.reshape(-1, 3)
        s = self.sharpness(self.step)
        self.model.env.prepare()
        rgbs, nors = [], []
        for i in range(0, o.shape[0], chunk):
            out = render_rays(self.model, o[i:i + chunk], d[i:i + chunk], s, self.cfg,
                              train=False)
            rgbs.append(out["rgb"])
            nors.append(out["normal"] * out["acc"][:, None])
        self.model.env.release()
        return {"rgb": torch.cat(rgbs).view(hh, ww, 3), "normal": torch.cat(nors).view(hh, ww, 3)}

    def write_preview(self) -> None:
        """Write ``preview/step_XXXXXX_{rgb,normal}.png`` for train view 0."""
        from voxnero.io.images import save_linear_png, write_png

        img = self.render_image(0)
        p = self.out / "preview"
        p.mkdir(exist_ok=True)
        save_linear_png(p / f"step_{self.step:06d}_rgb.png", img["rgb"].cpu().numpy())
        write_png(p / f"step_{self.step:06d}_normal.png",
                  (img["normal"].cpu().numpy() * 0.5 + 0.5).clip(0, 1))

    # ------------------------------------------------------------------ outputs
    def write_outputs(self) -> Path:
        """Final mesh (input frame), SDF grid, env map and summary JSON."""
        from voxnero.io.exr import write_exr
        from voxnero.mesh.io import save_mesh

        out = self.outputs
        out.mkdir(parents=True, exist_ok=True)
        mesh = self.extract(self.cfg.mesh_res)
        path = save_mesh(out / "mesh.ply", mesh, self.scene.norm)
        g = self.model.sdf
        np.savez_compressed(out / "sdf.npz", sdf=g.grid.data[0].cpu().numpy(),
                            bounds=g.bounds.cpu().numpy())
        write_exr(out / "envmap.exr", self.model.env.image().detach().cpu().numpy())
        self.write_decisions()
        summary = {"switches": asdict(self.sw), "steps": self.step,
                   "train_time_s": self.train_time, "grid_res": g.res,
                   "n_vertices": len(mesh.vertices), "n_triangles": len(mesh.triangles)}
        (out / "shape.json").write_text(json.dumps(summary, indent=2))
        return path

    # ------------------------------------------------------------------ loop
    def _log_line(self, fh, rec: dict[str, Any]) -> None:
        fh.write(json.dumps(rec) + "\n")
        fh.flush()

    def run(self) -> Path:
        """Train (resuming if a checkpoint exists) and write the outputs; returns mesh path."""
        from tqdm import tqdm

        cfg = self.cfg
        if cfg.grid.init_candidates or cfg.light.init_roughness_candidates:
            return self.race_starts()
        self.load_checkpoint()
        self.log(f"[shape] switches: {asdict(self.sw)}")
        for d in self.decisions:
            if d.step == 0:
                self.log(d.line())
        self.write_decisions()
        bar = tqdm(total=cfg.iters, initial=self.step, disable=not self.progress,
                   dynamic_ncols=True, desc="shape")
        last_ckpt = time.perf_counter()
        log_every = max(1, cfg.iters // 200)
        with open(self.out / "log.jsonl", "a") as fh, GracefulStop() as stop:
            try:
                while self.step < cfg.iters:
                    rec = self._timed_step(bar)
                    if self.step % log_every == 0 or self.step == cfg.iters:
                        bar.set_postfix(loss=f"{rec['loss']:.4f}", psnr=f"{rec['psnr']:.1f}",
                                        res=rec["res"])
                        self._log_line(fh, {"time": round(self.train_time, 2),
                                            "step": self.step, **rec})
                    if cfg.eval_every_s > 0 and self.eval_split is not None and (
                            self.train_time - self._last_eval >= cfg.eval_every_s
                            or self.step == cfg.iters):
                        self._last_eval = self.train_time
                        ch = self.evaluate()
                        if ch:
                            self._log_line(fh, {"time": round(self.train_time, 2),
                                                "step": self.step, "chamfer": ch["cd"],
                                                "acc": ch["acc"], "comp": ch["comp"]})
                            bar.write(f"[shape] step {self.step} t={self.train_time:.0f}s "
                                      f"chamfer {ch['cd']:.4f}")
                    if cfg.preview_every > 0 and self.step % cfg.preview_every == 0:
                        self.write_preview()
                    if time.perf_counter() - last_ckpt >= cfg.ckpt_every_s:
                        self.save_checkpoint()
                        last_ckpt = time.perf_counter()
                    if stop.flag:
                        raise KeyboardInterrupt
            except KeyboardInterrupt:
                bar.close()
                if stop.forced:  # a second signal cut a step short: keep the last checkpoint
                    self.log(f"[shape] stopped during step {self.step}; the last checkpoint is "
                             "kept, re-run the same command to resume from it")
                    raise
                self.save_checkpoint()
                self.log(f"[shape] stopped at step {self.step}; checkpoint saved, re-run the "
                         "same command to resume")
                raise
        bar.close()
        self.save_checkpoint()
        return self.write_outputs()
