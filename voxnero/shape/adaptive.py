"""Scene-adaptive modelling decisions of stage 1, from measurable evidence.

Each decision is a pure function of data (images, cameras, a surface) and of the user's switch:
"on"/"off" (or a fixed value) always wins over "auto". The trainer records every decision with
its evidence and reason in ``RUN/decisions.json`` and logs it.

* **background** — images that carried alpha were composited on a known colour, and images whose
  border is one constant colour (a studio backdrop, a constant environment) show nothing of the
  environment: no background model, the pixel is that colour ("alpha"). Otherwise the background
  is the distant environment, drawn by the env map ("distant"). Evidence: the transparent
  fraction (alpha < 0.5) or the fraction of border pixels within a tolerance of the median
  border colour. A *near* background (a table, a room) is detected by parallax: pixels of
  different views whose rays leave the region of interest in the same direction disagree in
  colour far beyond the texture inside one view (:mod:`voxnero.data.distant`); then a
  near-background field outside the unit sphere (:mod:`voxnero.fields.background`) is composited
  in front of the env map ("near").
* **grid resolution and sample counts** — a voxel finer than the footprint of one pixel at the
  object's distance is not constrained by any photo. The footprint is ``distance / focal`` (unit
  frame length per pixel, median over the training cameras, at the distance of the unit frame's
  origin, where the normalisation puts the object); the finest useful grid has voxel ≥ footprint,
  ``res_max = floor(2·bound / footprint) + 1``. The preset's resolutions are upper bounds; sample
  counts scale with the finest resolution kept.
* **self-occlusion** (NeRO's occlusion net + indirect light) — after the coarse grid has carved,
  the surface is extracted, the training cameras' view rays are cast at it and reflected about
  the facet normals; if fewer than :data:`SELF_OCCLUSION_MIN` of the reflected rays hit the
  object again, the object (nearly) never sees itself in reflection and ``L = L_direct`` is
  exact: the occlusion and indirect nets stay off.
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from voxnero.safety.folder import atomic_write_text

SELF_OCCLUSION_MIN = 0.005
"""Fraction of the cameras' reflected view rays that must hit the object itself for the
occlusion/indirect light model to be switched on. Set just above what a convex object measures
and well below what a true concavity does, because the measurement runs on a partly carved
surface that fills narrow gaps:

* convex objects measure 0–0.1 % on their reconstructions (sphere_gold, analytic spheres), and a
  sphere with 12° mean normal error (bumps far worse than any converged run, 1–5°) 0.26 %;
* two spheres 0.03 apart measure 5.5 % on the true surface but 0.5–1.1 % on the necked surface
  that training carves first (a smooth union with the same neck: 1.1 %, truth 4.6 %; tested).

The costs are lopsided, which also argues for the low side: the nets on a convex sphere cost
3–5 % of the time and 0.0086 → 0.0095 Chamfer; off on the pair, 0.0246 → 0.032 (128²)."""
BORDER_TOL = 0.02
"""Linear-radiance tolerance (absolute, plus the same relative) of a "constant" border pixel."""
BORDER_CONSTANT_MIN = 0.98
"""Fraction of border pixels that must match the border colour for a constant background."""
BORDER_WIDTH = 2
"""Width in pixels of the image border examined."""
NEAR_PARALLAX_DB = 5.0
"""dB by which the best direction-only fit of the background pixels (an env map) must fall short
of the views' own fit for the background to count as near (``parallax_db`` of
:func:`voxnero.data.distant.distant_background_evidence`; every third pixel here, bins of four
pixels). Measured: the dev scenes (environment at infinity) 0.6–0.7 dB, the DTU capture
dtu_scan97 (a table under the object) 11.3 dB; tests: a textured direction-only environment vs
a table."""


@dataclass
class Decision:
    """One recorded decision.

    Attributes:
        name: what is decided ("background", "grid_res", "occlusion", ...).
        value: the decided value (JSON-serialisable).
        setting: the user's switch value ("auto", "on", "off", ...).
        reason: one line for a human.
        evidence: the measured numbers the decision rests on.
        step: training step at which it was taken (0 = before training).
    """

    name: str
    value: Any
    setting: Any
    reason: str
    evidence: dict[str, Any] = field(default_factory=dict)
    step: int = 0

    def line(self) -> str:
        """One log line."""
        return f"[shape] decision {self.name} = {self.value} ({self.reason})"


def is_on(v: Any) -> bool:
    """A switch that is not off ("auto", "on", True)."""
    return v not in ("off", False)


def is_forced(v: Any) -> bool:
    """A switch the user set explicitly ("on"/"off"/bool), i.e. not "auto"."""
    return v != "auto"


# ------------------------------------------------------------------------- region of interest
def roi_decision(scene: Any) -> Decision:
    """The region of interest (the unit sphere of the working frame) as the loader chose it:
    rule, centre and radius in the input frame (``scene.meta["normalisation"]``)."""
    rec = dict(getattr(scene, "meta", {}).get("normalisation", {}) or {})
    method = rec.pop("method", "?")
    return Decision("region_of_interest", {"center": rec.get("center"),
                                           "radius": rec.get("scale")},
                    "bbox/center/radius" if "user" in method or "bbox" in method else "auto",
                    method, rec)


# ---------------------------------------------------------------------------------- background
def border_evidence(images: torch.Tensor | np.ndarray, width: int = BORDER_WIDTH,
                    tol: float = BORDER_TOL) -> dict[str, Any]:
    """How constant the image borders are.

    Args:
        images: ``(N, H, W, 3)`` linear RGB.
        width: border width in pixels.
        tol: tolerance; a pixel p matches colour c if ``max|p − c| ≤ tol·(1 + max c)``.

    Returns:
        ``{"border_color": [r, g, b] (median of all border pixels), "border_constant_fraction":
        fraction of border pixels that match it, "border_pixels": count}``.
    """
    im = torch.as_tensor(images, dtype=torch.float32)
    w = max(1, min(width, im.shape[1] // 2, im.shape[2] // 2))
    ring = torch.cat([im[:, :w].reshape(-1, 3), im[:, -w:].reshape(-1, 3),
                      im[:, w:-w, :w].reshape(-1, 3), im[:, w:-w, -w:].reshape(-1, 3)])
    c = ring.median(0).values
    match = (ring - c).abs().amax(-1) <= tol * (1.0 + float(c.max()))
    return {"border_color": [round(float(v), 6) for v in c],
            "border_constant_fraction": float(match.float().mean()),
            "border_pixels": int(ring.shape[0])}


def decide_background(setting: str, scene: Any) -> tuple[str, tuple[float, float, float],
                                                          Decision]:
    """Background model from the data (see the module docstring).

    Args:
        setting: ``light.background`` ("auto", "distant" or "alpha").
        scene: a scene with ``background`` ("alpha" if images had alpha), ``meta`` (``bg_color``)
            and, for the border test, ``split("train").images (N, H, W, 3)`` linear.

    Returns:
        ``(mode "distant"|"alpha", bg_color (r, g, b) linear, Decision)``.
    """
    color = tuple(float(v) for v in getattr(scene, "meta", {}).get("bg_color", (1.0, 1.0, 1.0)))
    ev: dict[str, Any] = {}
    train = None
    try:
        train = scene.split("train")
    except Exception:  # a bare scene description: no images to look at
        train = None
    alpha = getattr(train, "alpha", None) if train is not None else None
    if alpha is not None:
        ev["transparent_fraction"] = float((torch.as_tensor(alpha) < 0.5).float().mean())
    if getattr(scene, "background", "") != "alpha" and train is not None \
            and getattr(train, "images", None) is not None:
        ev.update(border_evidence(train.images))
    if setting != "auto":
        mode = setting
        reason = f"forced by light.background={setting}"
    elif getattr(scene, "background", "") == "alpha":
        mode, reason = "alpha", f"images carry alpha, composited on the known colour {color}"
    elif ev.get("border_constant_fraction", 0.0) >= BORDER_CONSTANT_MIN:
        mode = "alpha"
        color = tuple(ev["border_color"])
        reason = (f"{ev['border_constant_fraction']:.1%} of border pixels have one colour "
                  f"(≥ {BORDER_CONSTANT_MIN:.0%}): constant background, no background model")
    elif train is not None and getattr(train, "cameras", None) is not None and \
            _near(ev, train):
        mode = "near"
        reason = (f"the views disagree on background directions by {ev['parallax_db']:.1f} dB "
                  f"(≥ {NEAR_PARALLAX_DB:g}: an env map fits the background pixels to "
                  f"{ev['env_fit_psnr']:.1f} dB, each view to {ev['view_fit_psnr']:.1f} dB): "
                  "near background, a field outside the region of interest")
    else:
        mode = "distant"
        frac = ev.get("border_constant_fraction")
        reason = ("no alpha" + (f", border constant on only {frac:.1%}" if frac is not None
                                else "")
                  + (f", views agree on background directions ({ev['parallax_db']:.1f} dB < "
                     f"{NEAR_PARALLAX_DB:g})" if ev.get("parallax_db") is not None else "")
                  + ": distant environment drawn by the env map")
    return mode, color, Decision("background", mode, setting, reason, ev)


_PARALLAX_CACHE: dict[int, tuple[Any, dict[str, Any]]] = {}
"""Evidence per train split (by identity): each start of a race decides again, on the same data."""


def _near(ev: dict[str, Any], train: Any) -> bool:
    """Measure the background parallax into ``ev``; whether it says "near"."""
    from voxnero.data.distant import distant_background_evidence

    hit = _PARALLAX_CACHE.get(id(train))
    if hit is not None and hit[0] is train:
        ev["distant"] = copy.deepcopy(hit[1])
    else:
        # about 600k pixels looked at (every third pixel of the dev scenes and of DTU's views)
        stride = max(1, int(math.sqrt(train.images[..., 0].numel() / 6e5)))
        ev["distant"] = distant_background_evidence(train, stride=stride)
        _PARALLAX_CACHE.clear()
        _PARALLAX_CACHE[id(train)] = (train, copy.deepcopy(ev["distant"]))
    ev["parallax_db"] = ev["distant"]["parallax_db"]
    ev["env_fit_psnr"] = ev["distant"]["env_fit_psnr"]
    ev["view_fit_psnr"] = ev["distant"]["view_fit_psnr"]
    return ev["parallax_db"] is not None and ev["parallax_db"] >= NEAR_PARALLAX_DB


# ---------------------------------------------------------------------------------- resolution
def pixel_footprint(K: torch.Tensor, c2w: torch.Tensor) -> float:
    """Unit-frame length covered by one pixel at the distance of the origin (the object).

    Args:
        K: ``(N, 3, 3)`` intrinsics in pixels; c2w: ``(N, 4, 4)`` camera-to-world (unit frame).

    Returns:
        Median over cameras of ``|camera centre| / focal`` with focal = mean of fx, fy.
    """
    dist = c2w[:, :3, 3].double().norm(dim=-1)
    focal = 0.5 * (K[:, 0, 0] + K[:, 1, 1]).double()
    return float((dist / focal).median())


ENV_TEXEL_PIXELS = 4.0
"""Pixels of the photos across one texel of the coarse stage's env map (:func:`env_rows`)."""


def env_rows(K: torch.Tensor, cap: int, floor: int) -> int:
    """Rows of an equirectangular env map whose texel (π / rows radians) spans
    :data:`ENV_TEXEL_PIXELS` pixels of the photos, between ``floor`` and ``cap``.

    A finer map than the photos resolve lets the background absorb the object (on a 64² scene a
    256-row map took the whole sphere: the coarse stage found no hull); a coarser one leaves
    background detail to floaters of the density (docs/STAGE1.md, finding 19).

    Args:
        K: ``(N, 3, 3)`` intrinsics in pixels (one pixel ≈ 1 / focal radians at the centre).
        cap, floor: the preset's upper bound and the main map's rows.

    Returns:
        ``clamp(round(π · focal / ENV_TEXEL_PIXELS), floor, cap)`` with focal the median of the
        cameras' mean of fx and fy: 256² at 40° gives 276 (capped to 256), 64² gives 69.
    """
    focal = float((0.5 * (K[:, 0, 0] + K[:, 1, 1]).double()).median())
    rows = int(round(math.pi * focal / ENV_TEXEL_PIXELS))
    return max(floor, min(cap, rows))


def max_useful_res(footprint: float, bound: float) -> int:
    """Finest grid resolution whose voxel ``2·bound/(res − 1)`` is not below ``footprint``."""
    return int(math.floor(2.0 * bound / footprint)) + 1


def adapt_resolution(res: list[int], coarse: int, fine: int, coarse_keep: int, bound: float,
                     footprint: float, enabled: bool = True
                     ) -> tuple[list[int], tuple[int, int, int], Decision]:
    """Cap the grid resolutions and scale the sample counts by the pixel footprint.

    Args:
        res: the preset's SDF resolutions (upper bounds), coarse to fine.
        coarse, fine, coarse_keep: the preset's sample counts (upper bounds).
        bound: grid half-size (unit frame).
        footprint: :func:`pixel_footprint`.
        enabled: ``grid.res_auto``; False keeps the preset's values (recorded as forced).

    Returns:
        ``(resolutions, (coarse, fine, coarse_keep), Decision)``.
    """
    cap = max_useful_res(footprint, bound)
    ev = {"pixel_footprint": round(footprint, 6), "res_max": cap,
          "voxel_at_preset": round(2 * bound / (max(res) - 1), 6), "preset_res": list(res),
          "preset_samples": [coarse, fine, coarse_keep]}
    if not enabled:
        return list(res), (coarse, fine, coarse_keep), Decision(
            "grid_res", list(res), False, "forced by grid.res_auto=false", ev)
    new = [min(int(r), cap) for r in res]
    f = max(new) / max(res)
    c = min(coarse, max(16, math.ceil(coarse * f)))
    fi = min(fine, max(8, math.ceil(fine * f)))
    k = min(coarse_keep, c, max(8, math.ceil(coarse_keep * f)))
    if new == list(res):
        reason = (f"voxel {ev['voxel_at_preset']:.4f} ≥ pixel footprint {footprint:.4f}: "
                  "preset kept")
    else:
        reason = (f"pixel footprint {footprint:.4f} allows at most {cap}^3: grid {res} -> {new},"
                  f" samples {coarse}/{fine}/{coarse_keep} -> {c}/{fi}/{k}")
    return new, (c, fi, k), Decision("grid_res", {"res": new, "samples": [c, fi, k]}, True,
                                     reason, ev)


def adapt_config(cfg: Any, scene: Any, decisions: list[Decision] | None = None) -> Any:
    """A copy of a stage-1 config with the grid resolutions and sample counts capped by the pixel
    footprint of the scene's training cameras (:func:`adapt_resolution`, ``grid.res_auto``; the
    preset's values are upper bounds); the decision is appended to ``decisions``."""
    out = copy.deepcopy(cfg)
    try:
        cams = scene.split("train").cameras
        fp = pixel_footprint(cams.K, cams.c2w)
    except Exception:  # no cameras to measure: keep the preset
        return out
    sc = cfg.sampling
    res, (c, f, k), dec = adapt_resolution(cfg.grid.res, sc.coarse, sc.fine, sc.coarse_keep,
                                           cfg.grid.bound, fp, enabled=cfg.grid.res_auto)
    out.grid.res = res
    out.sampling.coarse, out.sampling.fine, out.sampling.coarse_keep = c, f, k
    if decisions is not None:
        decisions.append(dec)
    return out


# ------------------------------------------------------------------------------ self-occlusion
def decide_self_occlusion(fraction: float, n_rays: int, threshold: float = SELF_OCCLUSION_MIN
                          ) -> tuple[bool, str]:
    """Switch the occlusion/indirect model on iff the reflected rays see the object enough.

    Args:
        fraction: fraction of the cameras' reflected rays that hit the object
            (:func:`voxnero.shape.occlusion.reflected_hit_fraction`).
        n_rays: how many reflected rays were tested.
        threshold: :data:`SELF_OCCLUSION_MIN`.

    Returns:
        ``(on, reason)``.
    """
    if n_rays == 0:
        return False, "no view ray hit the surface yet: nothing measured"
    if fraction >= threshold:
        return True, (f"{fraction:.1%} of {n_rays} reflected view rays hit the object "
                      f"(≥ {threshold:.1%}): self-occlusion, occlusion + indirect on")
    return False, (f"{fraction:.2%} of {n_rays} reflected view rays hit the object "
                   f"(< {threshold:.1%}): no self-occlusion, direct light only")


def measure_self_occlusion(mesh: Any, origins: torch.Tensor, dirs: torch.Tensor,
                           smooth: int = 0, radius: float = 1.0) -> dict[str, Any]:
    """Evidence for :func:`decide_self_occlusion` on a surface (unit frame).

    Args:
        mesh: Open3D legacy triangle mesh (e.g. marching cubes of the coarse grid); trimmed to
            the sampling sphere and its large components first
            (:func:`voxnero.shape.occlusion.trim_mesh`).
        origins: ``(R, 3)`` training-camera ray origins; dirs: ``(R, 3)`` unit directions.
        smooth: Taubin iterations applied to the mesh first.
        radius: the renderer's sampling sphere (``sampling.radius``).

    Returns:
        ``{"reflected_hit_fraction", "reflected_rays", "view_rays", "mesh_edge"}``.
    """
    from voxnero.shape.occlusion import mean_edge_length, reflected_hit_fraction, trim_mesh

    mesh = trim_mesh(mesh, radius)
    o = origins.detach().cpu().double().numpy()
    d = dirs.detach().cpu().double().numpy()
    frac, k = reflected_hit_fraction(mesh, o, d, smooth=smooth)
    return {"reflected_hit_fraction": round(frac, 6), "reflected_rays": k,
            "view_rays": int(o.shape[0]), "mesh_edge": round(mean_edge_length(mesh), 6)}


# ---------------------------------------------------------------------------------- records
def write_decisions(path: str | Path, decisions: list[Decision]) -> Path:
    """Write ``decisions.json``: ``{name: {value, setting, reason, evidence, step}}``; a name
    decided several times keeps its latest entry and the earlier ones under ``history``."""
    out: dict[str, Any] = {}
    for d in decisions:
        rec = asdict(d)
        name = rec.pop("name")
        if name in out:
            hist = out[name].pop("history", [])
            rec["history"] = hist + [out[name]]
        out[name] = rec
    return atomic_write_text(path, json.dumps(out, indent=2, default=str))
