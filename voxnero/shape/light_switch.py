"""The light-model switches of stage 1 and their decisions.

NeRO's full light model adds an occlusion net (trained on ray-cast targets) and an indirect-light
net to the direct environment light. The user's ``light.*`` switches say "on", "off" or "auto";
:func:`resolve_switches` settles what is known before training, and for an "auto" occlusion
:func:`maybe_decide_occlusion` measures the carved surface's self-occlusion during training
(:func:`voxnero.shape.adaptive.measure_self_occlusion`) and switches the nets on or off
(:func:`enable_nets`, :func:`disable_nets`). Each decision is recorded with its evidence in the
trainer's ``decisions`` (``RUN/decisions.json``). The pure decision rules live in
:mod:`voxnero.shape.adaptive`; this module applies them to a running
:class:`~voxnero.shape.trainer.ShapeTrainer`.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import torch

from voxnero.fields.lights import IndirectNet, OcclusionNet
from voxnero.shape import adaptive, exposure, schedules
from voxnero.shape.config import ShapeConfig
from voxnero.shape.occlusion import OcclusionTargets, trim_mesh
from voxnero.shape.renderer import ShapeModel, Switches

if TYPE_CHECKING:
    from voxnero.shape.trainer import ShapeTrainer

VIEW_SEED_OFFSET = 7919
"""Added to ``seed`` for the view rays of the self-occlusion measurement (own RNG: the training
draws are unchanged)."""


def resolve_switches(cfg: ShapeConfig, scene: Any,
                     decisions: list[adaptive.Decision] | None = None) -> Switches:
    """Decide the switches known before training (logged, written to ``decisions.json``).

    * background: :func:`voxnero.shape.adaptive.decide_background` (alpha or a constant image
      border → "alpha" with that colour, else "distant").
    * occlusion / indirect: "on" builds NeRO's full light model from the start, "off" never;
      "auto" starts **on** (until the grid has carved nobody can tell, and nets switched on late
      do not undo a neck that formed without them) and is decided during training from the
      self-occlusion of the carved surface (:func:`decide_occlusion`): dropped on a convex
      surface.
    * metallic: "auto" means on (a dielectric is metallic = 0 within the model).
    * exposure: "on" / "off" as forced; "auto" is decided after the coarse stage
      (:mod:`voxnero.shape.exposure`).

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
        decisions.append(adaptive.roi_decision(scene))  # issue 22: the ROI and why
        decisions.append(dec)
        if adaptive.is_forced(lc.occlusion):
            why = f"forced by light.occlusion={lc.occlusion}"
        else:
            why = (f"auto: on until step {schedules.at(lc.decide_at, cfg)}, then "
                   "kept only if the carved surface sees itself")
        decisions.append(adaptive.Decision("occlusion", occ, lc.occlusion, why))
        decisions.append(adaptive.Decision(
            "indirect", ind, lc.indirect,
            "follows occlusion" if adaptive.is_on(lc.indirect) else "forced off"))
    expo, dec_expo = exposure.before_training(lc.exposure, cfg.coarse.iters > 0)
    if decisions is not None:
        decisions.append(dec_expo)
    return Switches(indirect=ind, occlusion=occ, metallic=adaptive.is_on(lc.metallic),
                    background=bg, bg_color=color, exposure=expo)


def enable_nets(model: ShapeModel, sw: Switches, opt: torch.optim.Optimizer, cfg: ShapeConfig,
                indirect: bool, add_to_optimizer: bool = True) -> None:
    """Create the occlusion (and indirect) nets now, on the model's device, and give them to the
    optimiser as the "light" group (``optim.lr_light``); ``sw`` is updated."""
    device = model.sdf.grid.device
    new = []
    if model.occlusion is None:
        model.occlusion = OcclusionNet(cfg.grid.feat_dim, cfg.light.hidden).to(device)
        new += list(model.occlusion.parameters())
    if indirect and model.indirect is None:
        model.indirect = IndirectNet(cfg.grid.feat_dim, cfg.light.hidden).to(device)
        new += list(model.indirect.parameters())
    sw.occlusion, sw.indirect = True, model.indirect is not None
    if add_to_optimizer and new:
        opt.add_param_group(dict(name="light", params=new, lr=cfg.optim.lr_light))


def disable_nets(model: ShapeModel, sw: Switches, opt: torch.optim.Optimizer,
                 remove_from_optimizer: bool = True) -> None:
    """Drop the occlusion and indirect nets (and their optimiser group and state): direct light
    only; ``sw`` is updated."""
    model.occlusion, model.indirect = None, None
    sw.occlusion, sw.indirect = False, False
    if remove_from_optimizer:
        keep = [g for g in opt.param_groups if g.get("name") != "light"]
        for g in opt.param_groups:
            if g.get("name") == "light":
                for q in g["params"]:
                    opt.state.pop(q, None)
        opt.param_groups[:] = keep


def occlusion_targets(tr: ShapeTrainer) -> OcclusionTargets | None:
    """Ray-cast occlusion targets on the trainer's current surface (None while nothing is
    carved)."""
    try:
        mesh = tr.extract(None, clean=False)
    except Exception as e:  # empty surface early on: no targets this time
        tr.log(f"[shape] occlusion targets skipped: {e}")
        return None
    lc = tr.cfg.light
    mesh = trim_mesh(mesh, tr.cfg.sampling.radius)
    if len(mesh.triangles) == 0:
        return None
    return OcclusionTargets(mesh, offset=lc.occlusion_offset, t_near=lc.occlusion_t_near,
                            smooth=lc.occlusion_smooth)


def view_rays(tr: ShapeTrainer, n: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` random training-camera rays ``(n, 3)`` origins and unit directions (unit frame),
    drawn with their own RNG."""
    gen = torch.Generator(device=tr.device).manual_seed(tr.cfg.seed + VIEW_SEED_OFFSET)
    o, d, _, _ = tr.pixel_batch(n, gen)
    return o, d


def maybe_decide_occlusion(tr: ShapeTrainer) -> None:
    """For ``light.occlusion=auto`` (the nets are on from the start): at ``light.decide_at``
    measure the self-occlusion of the carved surface; keep the occlusion/indirect model if it is
    above ``light.self_occlusion_min``, else drop it and measure again every
    ``loss.occlusion_every`` steps until ``light.decide_until``, switching fresh nets on if it
    rises above (then they stay on). When: :func:`voxnero.shape.schedules.occlusion_decision`.
    """
    if not tr.occ_pending:
        return
    what = schedules.occlusion_decision(tr.cfg, tr.step)
    if what == "close":
        tr.occ_pending = False
    elif what == "measure":
        decide_occlusion(tr)


def decide_occlusion(tr: ShapeTrainer) -> bool:
    """Measure the self-occlusion now, record the decision, switch the nets; returns whether the
    occlusion model is on."""
    lc = tr.cfg.light
    t0 = time.perf_counter()
    try:
        mesh = tr.extract(None, clean=False)
    except Exception as e:  # nothing carved yet: measure again later
        tr.log(f"[shape] self-occlusion not measured at step {tr.step}: {e}")
        return False
    o, d = view_rays(tr, lc.decide_rays)
    ev = adaptive.measure_self_occlusion(mesh, o, d, smooth=lc.occlusion_smooth,
                                         radius=tr.cfg.sampling.radius)
    on, why = adaptive.decide_self_occlusion(ev["reflected_hit_fraction"],
                                             ev["reflected_rays"], lc.self_occlusion_min)
    ev["grid_res"] = tr.model.sdf.res
    ev["seconds"] = round(time.perf_counter() - t0, 3)
    ind = on and adaptive.is_on(lc.indirect)
    for name, val, setting in (("occlusion", on, lc.occlusion),
                               ("indirect", ind, lc.indirect)):
        dec = adaptive.Decision(name, val, setting, why if name == "occlusion" else
                                ("follows occlusion" if adaptive.is_on(lc.indirect)
                                 else "forced off"), ev, tr.step)
        tr.decisions.append(dec)
    tr.log(tr.decisions[-2].line())
    if on:
        enable_nets(tr.model, tr.sw, tr.opt, tr.cfg, ind)
        tr.occ_pending = False
    elif tr.model.occlusion is not None:
        disable_nets(tr.model, tr.sw, tr.opt)
        tr.occ_targets = None
    tr.write_decisions()
    return on
