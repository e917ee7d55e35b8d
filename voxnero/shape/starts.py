"""The choice of start of stage 1: a race of complete runs.

Where the SDF starts matters for mirrors (a mirror barely moves from where it starts), and where
the roughness starts matters for how a mirror's surface settles (docs/STAGE1.md, findings 10, 13
to 15). With ``grid.init_candidates`` or ``light.init_roughness_candidates`` the program trains
one complete run per start in ``starts/<name>/`` and keeps the one whose final model fits the
photos best (:func:`fit_psnr`); with ``race_cut`` a start far behind the best finished one
at ``race_cut_at`` of its steps stops there and loses (:func:`cut_behind`). Each start is an
ordinary
:class:`~voxnero.shape.trainer.ShapeTrainer` run with its own checkpoints: re-running the
command resumes the unfinished start and skips the finished ones.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import torch

from voxnero.fields.lights import EnvLight
from voxnero.render.mip import resample_area
from voxnero.shape import adaptive, exposure, losses, run_files, schedules
from voxnero.shape.config import ShapeConfig
from voxnero.shape.renderer import as_photographed, background, render_rays

if TYPE_CHECKING:
    import numpy as np

    from voxnero.shape.coarse import Background, CoarseModel
    from voxnero.shape.config import CoarseConfig
    from voxnero.shape.trainer import ShapeTrainer

FIT_SEED_OFFSET = 104729
"""Added to ``seed`` for the fixed training pixels of :func:`fit_psnr` (the same for every start,
independent of the training draws)."""


def has_race(cfg: ShapeConfig) -> bool:
    """Whether ``cfg`` asks for more than one start: the coarse stage's start races the
    sphere of ``grid.init_radius`` unless ``coarse.race`` is off, and its opened shell with
    ``coarse.open_worst``."""
    coarse = cfg.coarse.iters > 0 and (cfg.coarse.race or cfg.coarse.open_worst)
    return bool(coarse or cfg.grid.init_candidates or cfg.light.init_roughness_candidates)


def near_start(cfg: ShapeConfig, background: str, decisions: list[adaptive.Decision]
               ) -> ShapeConfig:
    """The start of a scene whose background is near (a capture on a table, in a room): the
    coarse start alone, without the race of spheres, for ``coarse.near_iters`` steps.

    A sphere start assumes the object alone in free space inside the region of interest; with
    a near background the surface meets the table and leaves the region, and on dtu_scan97 the
    sphere r = 0.7 that fitted the photos 0.4 dB better scored held-out IoU 0.897 against the
    carved start's 0.923 (docs/STAGE1.md, finding 20). The race's time goes to the carved start
    instead: 1500 -> 2500 steps lifted its held-out IoU 0.929 -> 0.937 (seed 0) and 0.937 ->
    0.942 (seed 2) in less wall time than the race (finding 21). A decision "start" is appended
    when the rule changes anything.

    Args:
        cfg: the stage-1 config (with or without the coarse schedule).
        background: the decided background mode ("near", "distant", "alpha").
        decisions: the run's decisions (appended to).

    Returns:
        ``cfg`` unchanged unless the background is near and a coarse stage runs; then with
        ``coarse.race`` off, no ``grid.init_candidates`` (the light's roughness candidates
        still race) and ``iters`` = ``coarse.near_iters`` (0 keeps ``iters``).
    """
    c = cfg.coarse
    if background != "near" or c.iters <= 0:
        return cfg
    iters = c.near_iters or cfg.iters
    spheres = c.race or bool(cfg.grid.init_candidates) or c.open_worst
    if not spheres and iters == cfg.iters:
        return cfg
    decisions.append(adaptive.Decision(
        "start", "coarse", {"coarse.race": c.race, "grid.init_candidates": cfg.grid.init_candidates,
                            "coarse.open_worst": c.open_worst, "coarse.near_iters": c.near_iters},
        f"near background: the coarse start alone (a sphere start assumes the object alone in "
        f"free space; no opened start), {iters} steps (preset {cfg.iters})",
        {"race_skipped": spheres, "iters": iters, "preset_iters": cfg.iters}))
    return replace(cfg, iters=iters, coarse=replace(c, race=False, open_worst=False),
                   grid=replace(cfg.grid, init_candidates=[]))


def coarse_done(tr: ShapeTrainer) -> bool:
    """Whether ``tr``'s SDF already has its start from the coarse stage (a resumed run)."""
    return any(d.name == "coarse" for d in tr.decisions)


def coarse_env(env: EnvLight, height: int) -> EnvLight:
    """The env map the coarse stage fits: ``env`` itself at its own height (``height`` 0 or
    equal), else a new map of ``height`` rows started from it. The background seen in the photos
    has the pixels' detail (0.16° per pixel at 256² and 40°); what a 64-row map (2.8° per texel)
    cannot draw, the density explains with floaters in front of it, and thin parts of the
    object (a table's legs) are lost among them (docs/STAGE1.md, finding 19)."""
    if height in (0, env.height):
        return env
    return env.upsampled(height)


def coarse_start(tr: ShapeTrainer) -> None:
    """Give ``tr``'s SDF grid its start from the coarse free-space stage
    (:mod:`voxnero.shape.coarse`, :mod:`voxnero.shape.hull`) and record the decision "coarse".

    The coarse stage trains the density grid and ``tr``'s own env map (which the SDF stage goes
    on with); the filled occupancy's signed distance, resampled to the SDF grid, replaces the
    sphere. Its steps are not SDF steps (``tr.step`` stays 0); its seconds count in
    ``tr.train_time``.
    """
    import time

    import numpy as np

    from voxnero.fields.grid import resample
    from voxnero.shape import hull
    from voxnero.shape.coarse import CoarseModel, train_coarse

    c, lc = tr.cfg.coarse, tr.cfg.loss
    t0 = time.perf_counter()
    model = CoarseModel(c.res, tr.cfg.grid.bound, c.feat_dim, c.hidden, c.alpha_init
                        ).to(tr.device)
    bar = None
    if tr.progress:
        from tqdm import tqdm
        bar = tqdm(total=c.iters, desc="coarse", dynamic_ncols=True)

    def progress(it: int, loss: float) -> None:
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{loss:.4f}")

    m = tr.model
    # a known background colour (images with alpha) leaves the map to the lighting: no finer map;
    # else as fine as the photos resolve, up to coarse.env_height
    rows = 0
    if c.env_height and m.sw.background != "alpha":
        rows = adaptive.env_rows(tr.cams.K, c.env_height, m.env.height)
    env = coarse_env(m.env, rows)
    # the env map (or the known colour of images with alpha), without the near field: with it
    # the hull of dtu_scan97 fitted worse (held-out IoU 0.79 / 0.81 against 0.87 / 0.90,
    # docs/BENCHMARKS.md session 10)
    def bg(o: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        return background(m, d) if env is m.env else env.background(d)

    pixels = tr.pixels = tr.make_pixel_sampler()  # the SDF stage starts a fresh error map
    hist = train_coarse(model, env, lambda n: tr.train_batch(n)[:3],
                        lambda p, t: losses.color_loss(p, t, lc.charbonnier_eps, lc.color_space),
                        c.iters, c.rays, c.samples, c.lr_grid, c.lr_head, tr.cfg.optim.lr_env,
                        c.tv, tr.cfg.sampling.radius, tr.gen, progress, background=bg,
                        feedback=lambda p, t: pixels.feedback(
                            losses.pixel_error(p, t, lc.color_space)))
    tr.pixels = tr.make_pixel_sampler()
    if bar is not None:
        bar.close()
    if tr.cfg.light.exposure == "auto" and not tr.sw.exposure:
        exposure.decide_after_coarse(tr, model, bg)
    if env is not m.env:
        with torch.no_grad():  # the SDF stage goes on with the coarse map, area-averaged
            m.env.log_radiance.copy_(torch.log(resample_area(
                env.image(), m.env.height, 2 * m.env.height).clamp_min(1e-4)))
    alpha = model.voxel_alpha().cpu().numpy()
    if c.smooth > 0:
        from scipy import ndimage
        alpha = ndimage.gaussian_filter(alpha, c.smooth)
    inside = hull.solid(alpha, c.threshold, close=c.close)
    grown = {"added": 0}
    if c.bg_grow > 0 and inside.any():
        if m.sw.background == "near":
            # the coarse stage draws no near field: its background explains no pixel of a
            # capture's table, so every corner would look like object
            grown = {"added": 0, "skipped": "near background: the map does not draw it"}
        else:
            inside, grown = _grow_by_background(tr, model, bg, inside, c)
    sdf = hull.signed_distance(inside, model.density_grid.voxel)
    g = tr.model.sdf
    box = None
    if c.fit_box:
        box = hull.fitted_box(inside, model.density_grid.bounds.cpu().numpy(),
                              c.margin * model.density_grid.voxel, tr.cfg.grid.bound)
    coarse_sdf = torch.from_numpy(sdf)[None].to(g.grid)
    if not inside.any():
        pass  # nothing found: the sphere start stays (the decision says so)
    elif box is None:
        with torch.no_grad():
            g.grid.copy_(resample(coarse_sdf, g.res))
    else:
        fit_grid_to_box(tr, torch.from_numpy(box).float(), coarse_sdf,
                        model.density_grid.bounds)
    seconds = time.perf_counter() - t0
    tr.train_time += seconds
    n_in = int(inside.sum())
    tail = float(np.mean(hist[-20:])) if hist else float("nan")
    reason = (f"coarse free-space stage ({c.iters} steps, {c.res}^3 density): "
              f"{n_in} of {inside.size} voxels inside ({n_in / inside.size:.2%}) at opacity "
              f"> {c.threshold:g} per voxel, filled; the SDF starts from their signed distance")
    if n_in == 0:
        reason = ("coarse free-space stage found no occupied voxel at opacity > "
                  f"{c.threshold:g}: the SDF keeps its sphere start (r={tr.cfg.grid.init_radius:g};"
                  " too few coarse.iters, or check the photos and poses)")
    if grown.get("grown"):
        reason += (f"; grown by {grown['grown']} voxels the photos show as object "
                   f"(background ratio ≤ {grown['threshold']:g}, the hull core's "
                   f"{c.bg_quantile:g} quantile, within {c.bg_grow} voxels)")
    if box is not None:
        reason += (f"; SDF grid fitted to the object's box (side {box[1, 0] - box[0, 0]:.3f}, "
                   f"{g.res}^3, voxel {g.voxel:.4f})")
    tr.decisions.append(adaptive.Decision(
        "coarse", "hull" if n_in else "sphere", c.iters,
        reason, {"inside_voxels": n_in, "grid_res": c.res, "threshold": c.threshold,
                 "final_loss": round(tail, 5), "seconds": round(seconds, 2),
                 "max_alpha": round(float(alpha.max()), 4),
                 "sdf_box": None if box is None else box.round(4).tolist(),
                 "sdf_voxel": round(g.voxel, 6), "env_height": env.height,
                 "bg_grow": grown}, 0))


def _grow_by_background(tr: ShapeTrainer, model: CoarseModel, bg: Background,
                        inside: np.ndarray, c: CoarseConfig) -> tuple[np.ndarray, dict]:
    """``coarse.bg_grow``: the hull grown into the corners the photos show as object
    (:func:`voxnero.shape.hull.grow_seen_as_object` with :mod:`voxnero.shape.bg_votes`)."""
    import numpy as np

    from voxnero.fields.grid import grid_points
    from voxnero.shape import bg_votes, hull

    masks = bg_votes.background_pixels(tr.cams, tr.images.view(tr.n_img, tr.h, tr.w, 3), bg)
    corners = grid_points(model.density_grid.res, model.density_grid.bounds).reshape(-1, 3)

    def ratio_of(sel: np.ndarray) -> np.ndarray:
        pts = corners[torch.from_numpy(np.flatnonzero(sel)).to(corners.device)]
        return bg_votes.background_ratio(tr.cams, masks, pts).cpu().numpy()

    return hull.grow_seen_as_object(inside, ratio_of, c.bg_grow, c.bg_quantile,
                                    seed=tr.cfg.seed)


def with_coarse_schedule(cfg: ShapeConfig) -> ShapeConfig:
    """The config of a start from the coarse stage's hull: the SDF stage begins sharp
    (``coarse.s_start``), on ``coarse.sdf_res`` (first at ``coarse.sdf_first`` of it, upsampled
    at ``coarse.sdf_upsample_at``: finding 24) and with ``coarse.normal_smooth``,
    since its surface is already near the object's (a blurry start erodes thin parts, a normal
    smoothness one voxel wide removes rods of that width: docs/STAGE1.md, finding 17); its
    steps are blurred by ``coarse.update_smooth`` at ``coarse.lr_sdf_factor`` times the SDF
    learning rate (finding 18). Apply it once, to the config as given (the trainer does): the
    learning-rate factor multiplies."""
    c = cfg.coarse
    first = max(4, round(c.sdf_res * c.sdf_first))
    two = first < c.sdf_res
    grid = replace(cfg.grid, res=[first, c.sdf_res] if two else [c.sdf_res],
                   upsample_at=[c.sdf_upsample_at] if two else [])
    if c.update_smooth > 0:
        grid = replace(grid, grad_smooth=0.0, update_smooth=c.update_smooth)
    return replace(cfg, neus=replace(cfg.neus, s_start=c.s_start),
                   loss=replace(cfg.loss, normal_smooth=c.normal_smooth), grid=grid,
                   optim=replace(cfg.optim, lr_sdf=cfg.optim.lr_sdf * c.lr_sdf_factor))


def fit_grid_to_box(tr: ShapeTrainer, box: torch.Tensor, sdf: torch.Tensor,
                    sdf_bounds: torch.Tensor) -> None:
    """Move ``tr``'s SDF grid onto the cube ``box`` (``(2, 3)``) with the values of ``sdf``
    (``(1, R, R, R)`` over ``sdf_bounds``) resampled there, at the preset's resolutions capped
    again by the pixel footprint for the smaller cube (the decision "grid_res" is replaced), and
    rebuild the optimiser (no step has been taken yet)."""
    from voxnero.fields.grid import grid_points, grid_sample_points

    half = 0.5 * float(box[1, 0] - box[0, 0])
    cfg_in = with_coarse_schedule(tr.cfg_in)
    sc = cfg_in.sampling
    fp = adaptive.pixel_footprint(tr.cams.K, tr.cams.c2w)
    res, (c, f, k), dec = adaptive.adapt_resolution(
        cfg_in.grid.res, sc.coarse, sc.fine, sc.coarse_keep, half, fp, cfg_in.grid.res_auto)
    tr.cfg.grid.res = res
    tr.cfg.sampling.coarse, tr.cfg.sampling.fine, tr.cfg.sampling.coarse_keep = c, f, k
    co = tr.cfg_in.coarse
    # a user who set grid.res learns here that it does not shape this start's grid
    dec.reason += (f"; a carved start's grid is coarse.sdf_res = {co.sdf_res}, first at "
                   f"coarse.sdf_first = {co.sdf_first:g} of it: grid.res "
                   f"{list(tr.cfg_in.grid.res)} is the sphere starts' schedule (here its first "
                   "grid only sets the SDF step per voxel)")
    dec.evidence["from"] = "coarse.sdf_res"
    tr.decisions = [d for d in tr.decisions if d.name != "grid_res"] + [dec]
    r0 = schedules.grid_res(tr.cfg, tr.step)
    pts = grid_points(r0, box.to(sdf))
    values = grid_sample_points(sdf, pts.reshape(-1, 3), sdf_bounds.to(sdf)).view(1, r0, r0, r0)
    tr.model.sdf.set_box(box, values)
    tr.coarse_voxel = tr.model.sdf.voxel
    tr.opt = tr.make_optimizer()
    if tr.cfg.optim.lr_sdf_per_voxel:
        # the learning rates are tuned for the sphere start's first grid; Adam moves every voxel
        # by ~lr, so keep the step the same fraction of the (finer) voxel of the fitted grid
        # (a step of 0.7 voxel at lr 1e-2 left bowl_silver a noisy shell of genus 721)
        ref = 2.0 * tr.cfg_in.grid.bound / (tr.cfg_in.grid.res[0] - 1)
        for group in tr.opt.param_groups:
            if group.get("name") == "sdf":
                group["lr"] *= tr.model.sdf.voxel / ref


@torch.no_grad()
def fit_psnr(tr: ShapeTrainer, chunk: int = 8192) -> float:
    """PSNR (dB, linear RGB) of a trainer's current model on ``fit_rays`` training pixels drawn
    with a fixed seed (the same pixels for every start of a race), rendered as at test time."""
    gen = torch.Generator(device=tr.device).manual_seed(tr.cfg.seed + FIT_SEED_OFFSET)
    o, d, target, cam = tr.pixel_batch(tr.cfg.fit_rays, gen)
    s = schedules.sharpness(tr.cfg, tr.step)
    tr.model.env.prepare()
    nc = schedules.coarse_samples(tr.cfg, tr.step)
    rgb = torch.cat([render_rays(tr.model, o[i:i + chunk], d[i:i + chunk], s, tr.cfg,
                                 train=False, coarse=nc)["rgb"]
                     for i in range(0, o.shape[0], chunk)])
    rgb = as_photographed(tr.model, rgb, cam)
    tr.model.env.release()
    return losses.psnr(rgb, target)


def _runs_word(cuts: dict) -> str:
    """'complete runs', or 'runs' when some start stopped behind (``race_cut``)."""
    return "runs" if cuts else "complete runs"


def _cut_note(cut: dict | None) -> str:
    """A stopped start's note in a race decision's reason ('' for a finished one)."""
    if cut is None:
        return ""
    return f" (stopped at step {cut['step']}, {cut['best'] - cut['fit']:.2f} dB behind)"


def cut_behind(tr: ShapeTrainer) -> bool:
    """Whether a later start of a race stops now: at ``race_cut_at`` of its steps, its fit on
    the ``fit_rays`` pixels (:func:`fit_psnr`) is more than ``race_cut`` dB behind the race's
    best finished start (``tr.race_best``). Judged once, at that step (again on a resume that
    starts there: the fit is deterministic); the judgement goes to ``tr.cut`` and the log.
    Measuring the fit draws nothing from the run's generators, so a start that goes on trains
    exactly as without the cut."""
    cfg = tr.cfg
    if tr.race_best is None or cfg.race_cut <= 0 or tr.step != round(cfg.race_cut_at * cfg.iters):
        return False
    fit = fit_psnr(tr)
    behind = tr.race_best - fit
    stop = behind > cfg.race_cut
    tr.cut = {"step": tr.step, "fit": round(fit, 3), "best": tr.race_best, "stopped": stop}
    tr.log(f"[shape] at step {tr.step} of {cfg.iters}: fit {fit:.2f} dB, {behind:.2f} dB behind "
           f"the best finished start ({tr.race_best:.2f}); "
           + (f"more than race_cut = {cfg.race_cut:g} dB: stopped, it loses the race"
              if stop else f"within race_cut = {cfg.race_cut:g} dB: it goes on"))
    return stop


def mesh_genus(path: Path) -> int | None:
    """Genus of the largest component of the mesh file at ``path`` (None: not a closed
    2-manifold), :func:`voxnero.mesh.topology.mesh_topology`."""
    from voxnero.mesh.topology import mesh_topology

    return mesh_topology(path)[0]


def tied_with_one_material(opened: ShapeTrainer, fit: float, carved: float, co,
                           evidence: dict) -> bool:
    """Whether the opened start's finished run ``opened`` (fit ``fit`` dB) ties with the carved
    one (``carved`` dB) as the simpler surface: it fits at most ``co.open_margin`` better and
    at most ``co.open_tie`` worse, the carved run's worst patch was painted unlike the surface
    around it (material contrast ``evidence["material"]`` at least ``co.open_contrast``: a
    lid), and the opened run's own worst patch is painted like its surroundings (below it:
    :func:`voxnero.shape.proposals.worst_patch_evidence`). On a concave mirror the photos
    hardly tell the lid from the cavity (the bowl started from its true surface fits 0.12 dB
    better than its lid, docs/STAGE1.md finding 42); a lid needs a second material to explain
    them, the open surface does not. A solid object's worst patch is painted like its
    surroundings, so its opened start never ties. The measurement joins ``evidence["opened"]``.
    """
    if not (co.open_tie > 0 and carved - co.open_tie <= fit <= carved + co.open_margin):
        return False
    if evidence.get("material", {}).get("contrast", 0.0) < co.open_contrast:
        return False  # the carved run needed no second material: nothing to simplify
    from voxnero.shape import proposals

    _, own = proposals.worst_patch_evidence(opened, co)
    evidence["opened"] = own
    return own["material"]["contrast"] < co.open_contrast


def race(tr: ShapeTrainer) -> Path:
    """Race the starts of ``tr``'s config (as given, ``tr.cfg_in``); ``tr`` becomes the winner.

    1. Initial radii, at ``light.init_roughness``: ``grid.init_radius`` first, then
       ``grid.init_candidates`` (folders ``r<radius>``); another radius must beat
       ``init_radius``'s fit by ``grid.init_margin`` dB to replace it. With a coarse stage its
       carved start comes first (folder ``coarse``); with ``coarse.open_worst`` its opened
       shell (:mod:`voxnero.shape.proposals`, folder ``coarse_open``) follows it (when the
       carved run's worst-fitted patch's material contrast is at least ``coarse.open_gate``),
       and is kept if it fits ``coarse.open_margin`` dB better *and* its mesh has the carved
       run's genus, or if it ties (:func:`tied_with_one_material`).
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
    g, lc, co = tr.cfg_in.grid, tr.cfg_in.light, tr.cfg_in.coarse
    radii: list[float | None] = [g.init_radius] + [r for r in g.init_candidates
                                                    if r != g.init_radius]
    if co.iters > 0:  # the coarse stage's start first, the spheres as fall-backs
        radii = [None] + (radii if co.race else [])
    roughs = [r for r in lc.init_roughness_candidates if r != lc.init_roughness]
    runs: list[tuple[str, float, ShapeTrainer | None]] = []  # (folder name, fit, trainer)
    measured: list[adaptive.Decision] = []  # the coarse start's "auto" exposure decision
    seconds, steps = 0.0, 0
    cuts: dict[str, dict] = {}  # the starts stopped behind (race_cut): folder name -> judgement

    def start(radius: float | None, rough: float | None, k: int, n: int,
              edit: Callable[[ShapeTrainer], None] | None = None) -> float:
        nonlocal seconds, steps
        name = "coarse" if radius is None else f"r{radius:g}"
        name = name if edit is None else f"{name}_open"
        name = name if rough is None else f"{name}_rough{rough:g}"
        light = lc if rough is None else replace(lc, init_roughness=rough)
        sub = replace(tr.cfg_in, grid=replace(g, init_candidates=[]),
                      light=replace(light, init_roughness_candidates=[]))
        if radius is None:
            # the child's trainer applies the coarse schedule itself (once: its learning-rate
            # factor multiplies)
            sub = replace(sub, coarse=replace(co, race=False, open_worst=False))
        else:
            sub = replace(sub, grid=replace(sub.grid, init_radius=radius),
                          coarse=replace(co, iters=0))
        # a sphere start has no coarse stage to measure the photos on: it takes the coarse
        # start's "auto" decision
        taken = measured[0] if radius is not None and measured and lc.exposure == "auto" \
            else None
        if taken is not None:
            sub = replace(sub, light=replace(sub.light,
                                             exposure="on" if taken.value else "off"))
        folder = tr.out / "starts" / name
        tr.log(f"[shape] start {name} ({k} of {n}): a complete run in {folder}")
        child = type(tr)(sub, tr.scene, folder, tr.device, tr.progress, tr.log)
        child.start_edit = edit
        if taken is not None:
            child.decisions = [x for x in child.decisions if x.name != "exposure"] + [
                adaptive.Decision("exposure", taken.value, lc.exposure,
                                  "the coarse start's measurement: " + taken.reason,
                                  taken.evidence, 0)]
        if runs:
            child.race_best = runs[best_k][1]
        child.run()
        if radius is None and not measured:
            measured.extend(x for x in child.decisions if x.name == "exposure")
        seconds += child.train_time
        steps += child.step
        if child.cut is not None and child.cut["stopped"]:
            fit = child.cut["fit"]
            cuts[name] = child.cut
            tr.log(f"[shape] start {name}: stopped at step {child.step} of {child.cfg.iters} "
                   f"at {fit:.2f} dB ({child.train_time:.0f} s)")
        else:
            fit = fit_psnr(child)
            tr.log(f"[shape] start {name}: final fit {fit:.2f} dB ({child.train_time:.0f} s)")
        runs.append((name, round(fit, 3), child))
        return fit

    def keep_only(best: int) -> None:  # free the losers' models as the race goes
        for i, (nm, ft, _) in enumerate(runs):
            if i != best:
                runs[i] = (nm, ft, None)

    opening = co.iters > 0 and co.open_worst
    n = len(radii) + len(roughs) + int(opening)
    best_k = 0
    entries: list[tuple[str, float | None, Callable | None]] = []  # (name, radius, edit)
    proposal: dict = {}

    def judge(fit: float, margin: float | None = None) -> None:
        nonlocal best_k
        k = len(runs) - 1
        if margin is None:
            margin = g.init_margin if best_k == 0 else 0.0
        if k > 0 and runs[k][0] not in cuts and fit > runs[best_k][1] + margin:
            best_k = k
        keep_only(best_k)

    edit: Callable[[ShapeTrainer], None] | None = None
    for radius in radii:
        fit = start(radius, None, len(runs) + 1, n)
        entries.append(("coarse" if radius is None else f"r={radius:g}", radius, None))
        if radius is None and opening:  # measured before keep_only may free the model
            from voxnero.shape import proposals
            edit, proposal = proposals.propose_open(runs[-1][2], co)
            seconds += proposal["seconds"]
            if edit is None:
                tr.log("[shape] no opened start: " + (
                    "no worst-fitted patch" if not proposal["patch_cubes"] else
                    f"the worst-fitted patch is painted like the surface around it (material "
                    f"contrast {proposal['material']['contrast']:.2f} < coarse.open_gate "
                    f"{co.open_gate:g})"))
        judge(fit)
        if radius is None and opening and edit is not None:
            fit = start(None, None, len(runs) + 1, n, edit)
            entries.append(("coarse_open", None, edit))
            if runs[-1][0] in cuts:  # stopped behind: no mesh, it loses
                keep_only(best_k)
                continue
            # opening a cavity's lid adds no tunnel: a run that ends with another genus than
            # the carved one's made one (a shell's wall holed), whatever its fit
            genera = [mesh_genus(tr.out / "starts" / runs[k][0] / "mesh.ply")
                      for k in (len(runs) - 2, len(runs) - 1)]
            proposal["genus"] = genera
            if genera[0] is not None and genera[1] == genera[0]:
                tied = tied_with_one_material(runs[-1][2], fit, runs[-2][1], co, proposal)
                seconds += proposal.get("opened", {}).get("seconds", 0.0)  # measured or not
                if tied:
                    best_k = len(runs) - 1
                    tr.log(f"[shape] start coarse_open: {fit:.2f} dB against the carved "
                           f"start's {runs[-2][1]:.2f}, within {co.open_tie:g} dB, and one "
                           "material where it fits worst: the simpler surface, kept")
                    keep_only(best_k)
                else:
                    judge(fit, co.open_margin)
            else:
                tr.log(f"[shape] start coarse_open: genus {genera[1]} against the carved "
                       f"start's {genera[0]}: not kept")
                keep_only(best_k)
    k_radius = best_k
    names = [e[0] for e in entries]
    first = names[0] if co.iters > 0 else f"r={g.init_radius:g}"
    kept_name, kept_radius, kept_edit = entries[k_radius]
    evidence = {"radii": [e[1] for e in entries], "psnr": [runs[i][1] for i in range(len(entries))],
                "trial_steps": tr.cfg.iters}
    if opening:
        evidence["open"] = proposal
    if cuts:
        evidence["cut"] = dict(cuts)
    decisions = [adaptive.Decision(
        "start" if co.iters > 0 else "init_radius",
        kept_name if kept_radius is None else kept_radius,
        names if co.iters > 0 else [g.init_radius] + list(g.init_candidates),
        f"best fit of {len(entries)} {_runs_word(cuts)} to {tr.cfg.fit_rays} fixed training rays "
        f"(another start must beat {first} by {g.init_margin:g} dB"
        + (f", the opened one by {co.open_margin:g} dB with the carved one's genus"
           + (f", or within {co.open_tie:g} dB with one material where it fits worst"
              if co.open_tie > 0 else "")
           if "coarse_open" in names else "") + "): "
        + ", ".join(f"{nm}: {runs[i][1]:.2f} dB" + _cut_note(cuts.get(runs[i][0]))
                    for i, nm in enumerate(names)),
        evidence, tr.cfg.iters)]
    if roughs:
        n0 = len(entries)
        for j, rough in enumerate(roughs):
            k = n0 + j
            fit = start(kept_radius, rough, k + 1, n, kept_edit)
            if runs[k][0] not in cuts and fit > runs[best_k][1]:
                best_k = k
            keep_only(best_k)
        values = [lc.init_roughness] + roughs
        fits = [runs[k_radius][1]] + [runs[n0 + j][1] for j in range(len(roughs))]
        kept = lc.init_roughness if best_k < n0 else roughs[best_k - n0]
        decisions.append(adaptive.Decision(
            "init_roughness", kept, values,
            f"best fit of {len(values)} {_runs_word(cuts)} from {names[k_radius]} "
            f"({tr.cfg.fit_rays} fixed training rays): "
            + ", ".join(f"{v:g}: {p:.2f} dB" + _cut_note(cuts.get(runs[k][0]))
                        for v, p, k in zip(values, fits, [k_radius, *range(n0, n0 + len(roughs))],
                                           strict=True)),
            {"values": values, "psnr": fits, "radius": kept_radius}, tr.cfg.iters))
    name, _, win = runs[best_k]
    assert win is not None
    tr.outputs.mkdir(parents=True, exist_ok=True)
    for fname in ("mesh.ply", "sdf.npz", "envmap.exr", "shape.json"):
        shutil.copyfile(win.out / fname, tr.outputs / fname)
    if (win.out / run_files.EXPOSURE).is_file():  # written with the exposure switch on
        shutil.copyfile(win.out / run_files.EXPOSURE, tr.outputs / run_files.EXPOSURE)
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
    summary.update(train_time_s=seconds, race_steps=steps,
                   init_radius=kept_name if kept_radius is None else kept_radius,
                   init_roughness=win.cfg.light.init_roughness)
    (tr.outputs / "shape.json").write_text(json.dumps(summary, indent=2))
    return tr.outputs / "mesh.ply"
