"""Stage-1 training loop: one optimisation step, and the loop around it.

Orchestration only: the physics lives in :mod:`voxnero.shape.renderer` and the losses in
:mod:`voxnero.shape.losses`; what depends on the step alone in :mod:`voxnero.shape.schedules`;
the light-model switches ("auto" occlusion/indirect) in :mod:`voxnero.shape.light_switch`; the
race of starts (``grid.init_candidates``, ``light.init_roughness_candidates``) in
:mod:`voxnero.shape.starts`; checkpoints, ``log.jsonl``, ``decisions.json``, previews and the
outputs (``mesh.ply`` in the scene's input frame, ``sdf.npz``, ``envmap.exr``, ``shape.json``) in
:mod:`voxnero.shape.run_files`. Re-running the same command resumes from ``checkpoint.pt``,
bit-identically; SIGINT/SIGTERM finish the step and checkpoint (:mod:`voxnero.safety.stop`); a
loss that stays non-finite stops the run (:mod:`voxnero.safety.guard`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch

from voxnero.cameras.error_pixels import ErrorGuidedPixels
from voxnero.cameras.rays import pixel_rays, random_pixels
from voxnero.fields.grid import gaussian_blur3d
from voxnero.safety import fingerprint
from voxnero.safety.guard import NonFiniteGuard, nonfinite
from voxnero.safety.stop import GracefulStop
from voxnero.shape import adaptive, light_switch, losses, run_files, schedules, starts
from voxnero.shape.coarse_step import CoarseStep
from voxnero.shape.config import ShapeConfig
from voxnero.shape.objective import objective
from voxnero.shape.occlusion import OcclusionTargets
from voxnero.shape.renderer import ShapeModel, as_photographed, render_rays
from voxnero.shape.run_files import CKPT, STATE  # noqa: F401 - re-exported for callers


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
        self.scene, self.progress, self.log = scene, progress, log
        self.out = Path(out)
        self.out.mkdir(parents=True, exist_ok=True)
        self.outputs = self.out if outputs is None else Path(outputs)
        self.device = torch.device(device)
        if cfg.threads > 0:
            torch.set_num_threads(cfg.threads)
        torch.manual_seed(cfg.seed)
        self.gen = torch.Generator(device=self.device).manual_seed(cfg.seed)
        train = scene.split("train")
        self.cams = train.cameras.to(self.device) if hasattr(train.cameras, "to") \
            else train.cameras
        self.n_img, self.h, self.w = train.images.shape[:3]
        self.images = torch.as_tensor(train.images, dtype=torch.float32).reshape(-1, 3) \
            .to(self.device)
        self.decisions: list[adaptive.Decision] = []
        self.cfg_in = cfg
        """The config as given (before :func:`~voxnero.shape.adaptive.adapt_config`): each start
        of a race gets it."""
        if cfg.coarse.iters > 0:
            cfg = starts.with_coarse_schedule(cfg)
        self.cfg = cfg = adaptive.adapt_config(cfg, scene, self.decisions)
        self.sw = light_switch.resolve_switches(cfg, scene, self.decisions)
        # a near background: the carved start alone, with the race's time (starts.near_start)
        self.cfg = cfg = starts.near_start(cfg, self.sw.background, self.decisions)
        self.cfg_in = starts.near_start(self.cfg_in, self.sw.background, [])
        self.occ_pending = cfg.light.occlusion == "auto"
        """An "auto" occlusion not yet measured on (re-measured until ``decide_until``)."""
        self.fingerprint = fingerprint.make(cfg, scene=fingerprint.scene_digest(scene))
        """Scene and model-shaping settings, saved in the checkpoint and checked on resume."""
        self.guard = NonFiniteGuard("shape", self._nonfinite_cause, run_files.NONFINITE_FIX)
        self.model = ShapeModel(cfg, self.sw, n_images=self.n_img).to(self.device)
        self.coarse_voxel = self.model.sdf.voxel
        """Voxel of the first grid: smoothing lengths are fixed in space across resolutions."""
        self.opt = self.make_optimizer()
        self.pixels = self.make_pixel_sampler()
        """The training batches' pixels (uniform, or partly where the fit is worst)."""
        self.coarse_step: CoarseStep | None = None
        """The finishing phase's coarse SDF step (``grid.coarse_step``), made at its first use."""
        self.step, self.train_time, self.last_eval = 0, 0.0, 0.0
        self.start_edit: Callable[[ShapeTrainer], None] | None = None
        """Applied to the SDF right after the coarse start (a race's proposal,
        :func:`voxnero.shape.proposals.open_start`); not on resume."""
        self.race_best: float | None = None
        """A race's best finished fit (dB) when this run is one of its later starts: the run
        stops behind it (``race_cut``, :func:`voxnero.shape.starts.cut_behind`)."""
        self.cut: dict | None = None
        """Where ``race_cut`` was judged: step, fit, best, stopped (None: not judged)."""
        self.occ_targets: OcclusionTargets | None = None
        self.eval_split = None
        if "test" in getattr(scene, "splits", {}):
            te = scene.split("test")
            if te.depth is not None and te.masks is not None:
                self.eval_split = te

    @property
    def sdf_hold(self) -> int:
        """Steps from the start during which the SDF does not move (learning rate 0): the
        "open" decision's ``hold_steps`` (:func:`voxnero.shape.proposals.open_start`), else 0.
        Read from the decisions, so a resumed run keeps it."""
        return next((int(d.evidence.get("hold_steps", 0)) for d in self.decisions
                     if d.name == "open"), 0)

    def make_optimizer(self) -> torch.optim.Adam:
        """Adam over the model's parameter groups (one per learning rate)."""
        return torch.optim.Adam(self.model.param_groups(self.cfg), betas=(0.9, 0.99), eps=1e-15)

    def make_pixel_sampler(self) -> ErrorGuidedPixels:
        """A fresh sampler of training pixels (``sampling.error_*``); each stage gets one."""
        sc = self.cfg.sampling
        return ErrorGuidedPixels(self.n_img, self.h, self.w, sc.error_tile, sc.error_frac,
                                 sc.error_decay, sc.subpixel, self.device)

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

    # the run folder and the surface (:mod:`voxnero.shape.run_files`)
    def save_checkpoint(self) -> Path:
        return run_files.save_checkpoint(self)

    def load_checkpoint(self) -> bool:
        return run_files.load_checkpoint(self)

    def write_decisions(self) -> Path:
        return run_files.write_decisions(self)

    def extract(self, res: int | None = None, clean: bool = True):
        """Marching cubes of the current SDF grid (:func:`voxnero.shape.run_files.extract`)."""
        return run_files.extract(self.model, res, clean, self.cfg.sampling.radius)

    # ------------------------------------------------------------------ one step
    def pixel_batch(self, n: int, gen: torch.Generator
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """``n`` uniformly random training pixels drawn with ``gen``: ray origins and
        directions ``(n, 3)`` (unit frame), the photos' linear RGB ``(n, 3)`` there and the
        photo of each ``(n,)`` (long)."""
        return self.rays_of(*random_pixels(n, self.n_img, self.h, self.w, generator=gen,
                                           device=self.device))

    def train_batch(self, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor,
                                           torch.Tensor]:
        """As :meth:`pixel_batch`, drawn by :attr:`pixels` with the training RNG: a share
        ``sampling.error_frac`` where the fit is worst. Report the batch's per-pixel errors
        with ``self.pixels.feedback``."""
        return self.rays_of(*self.pixels.draw(n, self.gen))

    def rays_of(self, cam: torch.Tensor, pix: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Rays, photo colours and photo index of pixels ``pix (n, 2)`` in photos ``cam``."""
        pi = pix.long()
        target = self.images[(cam * self.h + pi[:, 1]) * self.w + pi[:, 0]]
        o, d = pixel_rays(self.cams, cam, pix)
        return o, d, target, cam

    def train_step(self) -> dict[str, float]:
        """One optimisation step; returns scalars for logging."""
        cfg, m, step = self.cfg, self.model, self.step
        res = schedules.grid_res(cfg, step)
        if res != m.sdf.res:
            self.set_resolution(res)
        s, lrf = schedules.sharpness(cfg, step), schedules.lr_factor(cfg, step)
        held = step < self.sdf_hold
        for g in self.opt.param_groups:
            g["lr"] = g.setdefault("base_lr", g["lr"]) * lrf
            if held and g.get("name") == "sdf":
                g["lr"] = 0.0
        light_switch.maybe_decide_occlusion(self)
        o, d, target, cam = self.train_batch(cfg.sampling.rays)
        m.env.prepare()
        out = render_rays(m, o, d, s, cfg, train=True, generator=self.gen,
                          coarse=schedules.coarse_samples(cfg, step))
        out["rgb"] = as_photographed(m, out["rgb"], cam)
        loss, t = objective(self, out, target)
        self.pixels.feedback(losses.pixel_error(out["rgb"], target, cfg.loss.color_space))
        self.opt.zero_grad(set_to_none=True)
        if not torch.isfinite(loss):
            # never let one bad batch poison the grids (Adam would spread the NaN everywhere)
            return self._skip("non-finite loss", s)
        loss.backward()
        g = m.sdf.grid
        if cfg.grid.grad_smooth > 0 and g.grad is not None:
            g.grad[0] = gaussian_blur3d(g.grad[0], cfg.grid.grad_smooth)
        if not all(torch.isfinite(p.grad).all() for p in m.parameters() if p.grad is not None):
            # a finite loss can still give a NaN gradient (0 * inf in a saturated exp): skip
            self.opt.zero_grad(set_to_none=True)
            return self._skip("non-finite gradient", s)
        before = g.detach().clone() if cfg.grid.update_smooth > 0 else None
        coarse = (cfg.grid.coarse_step > 0 and g.grad is not None
                  and step >= schedules.at(cfg.neus.final_at, cfg))
        self.opt.step()
        if before is not None:
            with torch.no_grad():
                g[0] = before[0] + gaussian_blur3d(g[0] - before[0], cfg.grid.update_smooth)
        if coarse:  # Adam leaves .grad as it was: no copy needed
            grp = next(x for x in self.opt.param_groups if x.get("name") == "sdf")
            if self.coarse_step is None:  # the SDF group's own Adam constants
                self.coarse_step = CoarseStep(cfg.grid.coarse_step, grp["betas"], grp["eps"])
            self.coarse_step.step(g.data, g.grad, grp["lr"])
        m.env.release()
        return {"loss": float(loss.detach()), **{k: float(v.detach()) for k, v in t.items()},
                "psnr": losses.psnr(out["rgb"], target), "s": s, "res": m.sdf.res}

    def _skip(self, what: str, s: float) -> dict[str, float]:
        """End a step without an update (``what`` was non-finite); its log record."""
        self.model.env.release()
        self.log(f"[shape] step {self.step}: {what}, step skipped")
        return {"loss": float("nan"), "color": float("nan"), "eik": float("nan"),
                "occ": 0.0, "nsmooth": 0.0, "psnr": 0.0, "s": s, "res": self.model.sdf.res}

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

    # ------------------------------------------------------------------ loop
    def run(self) -> Path | None:
        """Train (resuming if a checkpoint exists) and write the outputs; returns mesh path.
        With several starts, :func:`voxnero.shape.starts.race` runs one complete run each; a
        start of it that falls too far behind (``race_cut``) stops with its checkpoint and no
        outputs, and returns None."""
        from tqdm import tqdm

        cfg = self.cfg
        if starts.has_race(cfg):
            return starts.race(self)
        self.load_checkpoint()
        if cfg.coarse.iters > 0 and not starts.coarse_done(self):
            starts.coarse_start(self)
            if self.start_edit is not None:
                self.start_edit(self)
            self.save_checkpoint()
        self.log(f"[shape] switches: {asdict(self.sw)}")
        for d in self.decisions:
            if d.step == 0:
                self.log(d.line())
        self.write_decisions()
        bar = tqdm(total=cfg.iters, initial=self.step, disable=not self.progress,
                   dynamic_ncols=True, desc="shape")
        last_ckpt = time.perf_counter()
        with open(self.out / "log.jsonl", "a") as fh, GracefulStop() as stop:
            try:
                while self.step < cfg.iters:
                    if starts.cut_behind(self):
                        break
                    t0 = time.perf_counter()
                    rec = self.train_step()
                    self.guard.update(math.isfinite(rec["loss"]), self.step,
                                      last=self.step + 1 >= cfg.iters)
                    self.step += 1
                    self.train_time += time.perf_counter() - t0
                    bar.update(1)
                    run_files.after_step(self, fh, bar, rec)
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
        if self.cut is not None and self.cut["stopped"]:
            return None
        return run_files.write_outputs(self)
