"""Stage 1's per-photo exposure switch: measured after the coarse stage, recorded, applied.

``light.exposure=auto`` asks whether the photos were taken at one exposure and white balance.
After the coarse stage (a free density and colour fitted to all photos at once, so it renders
their consensus), every photo's well-exposed pixels are rendered and compared with the photo:
the median log ratio per photo and channel is that photo's gain relative to the others
(:func:`voxnero.fields.exposure.measure_log_gains`). On when they spread by
``light.exposure_min_spread`` or more and the gains of the object's and of the background's
pixels agree (``light.exposure_min_agreement``: :func:`decide`); the learnable gains
(:class:`voxnero.fields.exposure.ImageGains`) then start from the measured ratios. A scene rendered
at one exposure measures well under the line; the decision and the per-photo gains go to
``decisions.json``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import torch

from voxnero.cameras.rays import pixel_rays
from voxnero.fields.exposure import gain_spread, measure_log_gains
from voxnero.shape import adaptive

if TYPE_CHECKING:
    from voxnero.shape.coarse import CoarseModel
    from voxnero.shape.trainer import ShapeTrainer

SEED_OFFSET = 31337
"""Added to ``seed`` for the measurement's pixels (own RNG: the training draws are unchanged)."""


def before_training(setting: str, has_coarse: bool) -> tuple[bool, adaptive.Decision]:
    """The switch known before training and its record: "on" / "off" as forced; "auto" off
    for now (decided after the coarse stage, or off for good without one)."""
    if setting in ("on", "off"):
        return setting == "on", adaptive.Decision("exposure", setting == "on", setting,
                                                  f"forced by light.exposure={setting}")
    why = ("auto: measured after the coarse stage (per-photo gains of the photos against the "
           "coarse model's renders)" if has_coarse else
           "auto without a coarse stage: off (nothing to measure the photos against)")
    return False, adaptive.Decision("exposure", False, setting, why)


@torch.no_grad()
def decide_after_coarse(tr: ShapeTrainer, model: CoarseModel,
                        background: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
                        chunk: int = 8192) -> bool:
    """Measure the photos' gains against the fitted coarse ``model`` (over ``background``),
    record the decision "exposure" and switch the gains on if they spread; returns whether on.
    """
    from voxnero.shape.coarse import render_coarse

    lc, c = tr.cfg.light, tr.cfg.coarse
    t0 = time.perf_counter()
    gen = torch.Generator(device=tr.device).manual_seed(tr.cfg.seed + SEED_OFFSET)
    n = lc.exposure_pixels
    cam = torch.arange(tr.n_img, device=tr.device).repeat_interleave(n)
    flat = torch.randint(0, tr.h * tr.w, (cam.numel(),), generator=gen, device=tr.device)
    pix = torch.stack([flat % tr.w, flat // tr.w], -1).float() + 0.5
    target = tr.images[cam * tr.h * tr.w + flat]
    o, d = pixel_rays(tr.cams, cam, pix)
    outs = [render_coarse(model, background, o[i:i + chunk], d[i:i + chunk], c.samples,
                          tr.cfg.sampling.radius, train=False)
            for i in range(0, o.shape[0], chunk)]
    pred = torch.cat([x["rgb"] for x in outs])
    acc = torch.cat([x["acc"] for x in outs])
    return decide(tr, pred, target, cam, acc > 0.5, time.perf_counter() - t0)


def decide(tr: ShapeTrainer, pred: torch.Tensor, target: torch.Tensor, cam: torch.Tensor,
           on_object: torch.Tensor, seconds: float = 0.0) -> bool:
    """Decide "exposure" from renders ``pred`` ``(R, 3)`` of training pixels of photos ``cam``
    ``(R,)`` against the photos ``target`` ``(R, 3)`` (linear RGB); record it in
    ``tr.decisions`` and switch the gains on, from the measured ratios, if the photos need them.

    An exposure scales a whole photo: the gains measured on the object's pixels and on the
    background's (``on_object`` ``(R,)`` bool) must agree. A model's misfit of the object (a
    mirror's reflections, which the coarse model draws poorly) also differs from photo to
    photo, but leaves the background alone. On when the gains spread by
    ``light.exposure_min_spread`` or more and the two sets correlate by
    ``light.exposure_min_agreement`` or more over the photos."""
    lc = tr.cfg.light
    log_g, used, explained = measure_log_gains(pred, target, cam, tr.n_img)
    spread = gain_spread(log_g)
    agree = _agreement([measure_log_gains(pred[m], target[m], cam[m], tr.n_img)[:2]
                        for m in (on_object, ~on_object)])
    on = spread >= lc.exposure_min_spread and agree >= lc.exposure_min_agreement
    gains = torch.exp(log_g)
    lum = gains.mean(-1)
    ev = {"spread": round(spread, 4), "min_spread": lc.exposure_min_spread,
          "explained": round(explained, 4), "object_background_agreement": round(agree, 4),
          "min_agreement": lc.exposure_min_agreement,
          "gain_min": round(float(lum.min()), 3), "gain_max": round(float(lum.max()), 3),
          "pixels_used_median": int(used.median()), "seconds": round(seconds, 2),
          "gains": [[round(float(v), 3) for v in row] for row in gains]}
    why = (f"the photos' gains against the coarse model spread by {spread:.3f} (std of the log "
           f"gain, {float(lum.min()):.2f}-{float(lum.max()):.2f}x; needs "
           f"{lc.exposure_min_spread:g}), object and background gains correlate by {agree:.2f} "
           f"(needs {lc.exposure_min_agreement:g}): "
           + ("a gain per photo and channel, started there" if on
              else "one exposure for all photos"))
    tr.decisions = [x for x in tr.decisions if x.name != "exposure"]
    tr.decisions.append(adaptive.Decision("exposure", on, lc.exposure, why, ev, 0))
    if on:
        enable(tr, log_g)
    return on


def enable(tr: ShapeTrainer, log_init: torch.Tensor | None = None) -> None:
    """Switch the trainer's per-photo gains on (from ``log_init`` ``(n_img, 3)`` if given) and
    give them their learning rate."""
    g = tr.model.gains
    if g is None:
        raise RuntimeError("the model has no per-photo gains (light.exposure=off)")
    if log_init is not None:
        with torch.no_grad():
            g.log_gain.copy_(log_init.to(g.log_gain))
    tr.sw.exposure = True
    for group in tr.opt.param_groups:
        if group.get("name") == "gains":
            group["lr"] = group["base_lr"] = tr.cfg.light.exposure_lr


def _agreement(parts: list[tuple[torch.Tensor, torch.Tensor]]) -> float:
    """Pearson correlation over the photos (those with >= 16 pixels in both parts) of the
    mean-over-channels log gains of two pixel sets; 0 with fewer than 3 such photos."""
    (ga, ua), (gb, ub) = parts
    both = (ua >= 16) & (ub >= 16)
    if int(both.sum()) < 3:
        return 0.0
    a, b = ga[both].mean(-1), gb[both].mean(-1)
    a, b = a - a.mean(), b - b.mean()
    den = float(a.norm() * b.norm())
    return float((a * b).sum()) / den if den > 0 else 0.0
