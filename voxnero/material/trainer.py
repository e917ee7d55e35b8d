"""Stage-2 training loop: materials and env map on the fixed mesh.

Owns the loop, the optimisers, the learning-rate schedule, checkpoints (``checkpoint.pt``,
resumed automatically; with the run's fingerprint, so that a resume on another mesh, scene or
other settings is refused; never with NaN/Inf state; written after the step during which
SIGINT/SIGTERM arrived, :mod:`voxnero.safety`) and the progress bar; a loss that stays non-finite
stops the run (:mod:`voxnero.safety.guard`). The physics lives in
:mod:`voxnero.material.render`. Loss, per step::

    mean |srgb(clip(L_pred)) - srgb(L_target)|²  over object pixels (Monte Carlo L_pred)
  + mean |srgb(clip(env(d))) - srgb(L_target)|²  over background pixels (environment at infinity)
  + smooth · material smoothness + range_prior · (m (1 − m) + raw²) + env_smooth · TV(log env)
  + normals.prior · mean |n − n0|²  (learned shading normals, :mod:`voxnero.material.normals`)

Both sides are compared in sRGB after clipping the prediction to [0, 1], as the 8-bit
training images were made (clipped highlights give no gradient above 1).
"""

from __future__ import annotations

import copy
import itertools
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from voxnero.errors import RunFolderError
from voxnero.fields.lights import EnvLight
from voxnero.io.color import linear_to_srgb, srgb_slope
from voxnero.material.config import MaterialConfig
from voxnero.material.field import VertexMaterial, activated, make_field
from voxnero.material.lights import (
    LOG_MAX,
    LOG_MIN,
    IndirectLight,
    background_coverage,
    init_from_background,
)
from voxnero.material.normals import RefinedNormals
from voxnero.material.regions import material_features, mesh_average, two_materials
from voxnero.material.render import Bounces, Strategies, env_sampler, shade
from voxnero.material.surface import Geometry, SurfaceCache
from voxnero.render.latlong import envmap_lookup, latlong_blur
from voxnero.render.sampling import sample_cosine
from voxnero.safety import fingerprint
from voxnero.safety.guard import NonFiniteGuard, check_finite, nonfinite
from voxnero.safety.stop import GracefulStop

NONFINITE_FIX = ("lower lr_material / lr_env, check the mesh (input frame) and the scene's "
                 "images, then re-run with --fresh")


def srgb_clipped(lin: torch.Tensor) -> torch.Tensor:
    """sRGB encoding of linear values clipped to [0, 1] (how the 8-bit inputs were made)."""
    return linear_to_srgb(lin.clamp(0.0, 1.0))


def decorrelated_loss(pred: torch.Tensor, target: torch.Tensor, linearised: bool = True
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Object loss of two independent Monte Carlo estimates of the same pixels.

    E[(p1 − t)(p2 − t)] = (E p − t)²: no variance term, which would favour materials whose
    estimate is less noisy. ``linearised``: the sRGB error linearised at the photo,
    g'(t)² (p1 − t)(p2 − t) on linear values clipped to [0, 1] (g = sRGB encoding), whose
    expectation is g'(t)² (E p − t)²: zero gradient at E p = t. Otherwise
    (g(p1) − g(t))(g(p2) − g(t)), whose minimum lies at E g(p) = g(t), i.e. at E p > t by
    Jensen (g is concave): a noisy estimate is pushed brighter, or toward a less noisy lobe.

    Args:
        pred: (2B, 3) linear estimates, the first B and last B independent for the same
            pixels.
        target: (B, 3) linear photo values (decoded 8-bit sRGB, in [0, 1]).
        linearised: see above.

    Returns:
        (loss, mse): the scalar loss (differentiable) and the detached sRGB MSE of the mean
        of the two estimates (for logging).
    """
    p1, p2 = srgb_clipped(pred).chunk(2)
    g_t = linear_to_srgb(target)
    if linearised:
        t = target.clamp(0.0, 1.0)
        q1, q2 = pred.clamp(0.0, 1.0).chunk(2)
        loss = (srgb_slope(t) ** 2 * (q1 - t) * (q2 - t)).mean()
    else:
        loss = ((p1 - g_t) * (p2 - g_t)).mean()
    return loss, ((0.5 * (p1 + p2) - g_t) ** 2).mean().detach()


def needs_indirect(geom: Geometry, cache: SurfaceCache, n_points: int = 4096,
                   generator: torch.Generator | None = None) -> float:
    """Fraction of cosine-distributed secondary rays from cached points that hit the mesh.

    Returns:
        A fraction in [0, 1]: about 0 for a convex object.
    """
    N = cache.x.shape[0]
    if N == 0:
        return 0.0
    idx = torch.randint(0, N, (min(n_points, N),), generator=generator).to(cache.x.device)
    u = torch.rand((idx.shape[0], 2), generator=generator).to(cache.x.device)
    l, _ = sample_cosine(u, cache.n[idx])
    o = geom.spawn(cache.tri[idx], cache.x[idx], l)
    return float(geom.occluded(o, l).float().mean())


SECONDARY_HIT_MIN = 1e-3
"""Fraction of cosine secondary rays hitting the mesh below which "auto" models neither shadows
nor inter-reflection. Those rays are all that the casts and the indirect estimate change, so
the rendered light moves by about this fraction on average, far under the Monte Carlo noise of
a training estimate (a few samples per strategy). Marching-cubes meshes of convex objects
measure 0–0.07 % (facet-scale dents), self-occluding ones 3.9–4.6 % (the dev torus), the
corpus's self-reflecting objects up to 18 % (docs/STAGE2.md)."""


TRACED_HIT_MIN = 0.08
"""Fraction of cosine secondary rays hitting the mesh from which "auto" traces inter-reflections
instead of the split-sum estimate at the first hit. Measured with the TRUE mesh, material and
env map (docs/STAGE2.md): the chrome knot (12.7 %) reads 27.8 dB traced against 26.6 dB
split-sum (28.3 / 26.6 dB at 32 spp); the ceramic dev torus (4.2 %) 27.56 dB traced against
27.83 dB split-sum at 48 spp (the one-sample bounce adds noise that its few hits do not pay
back). Placed between the two; the corpus's other self-occluding scenes decide it too."""


def decide_secondary(fraction: float, visibility: Any, indirect: str) -> tuple[str, bool]:
    """Stage-2 light model from the measured secondary-ray hit fraction.

    Args:
        fraction: :func:`needs_indirect` (0 when ``visibility`` is off: nothing measured).
        visibility: ``render.visibility`` ("auto", "on"/True, "off"/False).
        indirect: ``light.indirect`` ("auto", "traced", "splitsum", "off").

    Returns:
        ``(indirect_model, visibility_casts)``: the model of light along secondary rays that hit
        the object ("traced", "splitsum" or "off") and whether rays are cast at all. "auto"
        casts at :data:`SECONDARY_HIT_MIN` or more, with the split-sum estimate at the first
        hit, and traces inter-reflections at :data:`TRACED_HIT_MIN` or more (where the
        split-sum was measured worse); forced settings win.
    """
    seen = fraction >= SECONDARY_HIT_MIN
    if indirect == "auto":
        model = "traced" if fraction >= TRACED_HIT_MIN else "splitsum" if seen else "off"
    else:
        model = indirect
    casts = visibility in ("on", True) or (visibility == "auto" and seen)
    return model, casts

RELABEL_PASSES = 4
"""Most passes of ``relabel_boundary`` at each ``field.relabel_at`` point."""

PROBE_AVERAGE_ROUNDS = 4
"""Rounds of neighbour averaging of the probe's per-vertex features before the two-means split
(:func:`voxnero.material.regions.mesh_average`): the probe's free per-vertex values are noisy
(Monte Carlo gradients, no smoothness), a boundary moves by at most this many edges, and the
photos place it afterwards (``relabel_boundary``)."""


class MaterialTrainer:
    """Fits the material field and the env map to the cached training pixels."""

    def __init__(self, cfg: MaterialConfig, geom: Geometry, cache: SurfaceCache,
                 log: Callable[[str], None] = print, device: torch.device | str = "cpu",
                 env_init: torch.Tensor | None = None, sources: dict[str, str] | None = None):
        """Args:
            cfg: resolved stage-2 config.
            geom: fixed mesh (unit frame).
            cache: primary hits and background pixels (:func:`surface.build_cache`).
            log: where progress lines go.
            device: torch device of the parameters (Open3D casts stay on the CPU).
            env_init: (H, W, 3) linear map to start from (default: background pixels averaged
                into a map of height ``light.env_height[0]``).
            sources: digests of what the run is made from (``{"scene": ..., "mesh": ...}``,
                :mod:`voxnero.safety.fingerprint`), saved in checkpoints and checked on resume.
        """
        self.device = torch.device(device)
        geom = geom.to(self.device)
        cache = SurfaceCache(**{k: v.to(self.device) if isinstance(v, torch.Tensor) else v
                                for k, v in vars(cache).items()})
        self.cfg, self.geom, self.cache, self.log = cfg, geom, cache, log
        self.gen = torch.Generator().manual_seed(cfg.seed)
        fc = cfg.field
        self.field = make_field(fc.kind, geom, fc.grid_res, fc.init_albedo, fc.init_metallic,
                                fc.init_roughness).to(self.device)
        nc = cfg.normals
        self.normals = RefinedNormals(geom.vertex_normals, geom.triangles, nc.rounds).to(
            self.device) if nc.refine else None
        self.heights = list(cfg.light.env_height)
        self.level = 0
        if env_init is None:
            env_init = init_from_background(cache.bg_dirs.cpu(), cache.bg_rgb.cpu(),
                                            self.heights[0])
        self.env = EnvLight.from_image(env_init.to(self.device), LOG_MAX, LOG_MIN)
        self.spp = Strategies(cfg.render.spp_cos, cfg.render.spp_ggx, cfg.render.spp_env)
        vis = cfg.render.visibility
        frac = needs_indirect(geom, cache, generator=self.gen) if vis not in ("off", False) \
            else 0.0
        self.indirect_model, self.visibility = decide_secondary(frac, vis, cfg.light.indirect)
        self.use_indirect = self.visibility and self.indirect_model != "off"
        lc = cfg.light
        self.bounces = Bounces(lc.bounces, lc.rr_bounces, lc.rr_survive,
                               Strategies(lc.bounce_spp, lc.bounce_spp, lc.bounce_spp)) \
            if self.indirect_model == "traced" else None
        self.decisions = {"secondary_hit_fraction": frac, "indirect": self.use_indirect,
                          "indirect_model": self.indirect_model if self.visibility else "off",
                          "visibility_casts": self.visibility,
                          "env_sampling": True}
        if self.bounces is not None:
            self.decisions["bounces"] = {"traced": lc.bounces, "russian_roulette": lc.rr_bounces,
                                         "survive": lc.rr_survive, "spp": lc.bounce_spp}
        what = {"traced": f"traced on the mesh ({lc.bounces} bounces, then up to "
                          f"{lc.rr_bounces} by Russian roulette)",
                "splitsum": "split-sum estimate", "off": "off"}[self.indirect_model]
        log(f"[material] secondary rays hitting the object: {100 * frac:.2f} % -> indirect "
            f"light {what if self.visibility else 'off'}, visibility casts "
            f"{'on' if self.visibility else 'off'}; env-map importance sampling on")
        self.step = 0
        self.sources = dict(sources or {})
        self.guard = NonFiniteGuard("material", self._nonfinite_cause, NONFINITE_FIX)
        self._unseen: torch.Tensor | None = None  # (H, W, 1) env cells no photo sees directly
        self._racing = False  # inside the metalness race or the materials' probe
        self._probing = False  # the probe: smoothness off, env map held (_probe_features)
        self._relabel_from = -1  # relabel_at points up to this step are done
        self._make_optimisers()

    # ------------------------------------------------------------------ setup
    def _make_optimisers(self) -> None:
        self.opt_mat = torch.optim.Adam(self.field.parameters(), lr=self.cfg.lr_material)
        self.opt_env = torch.optim.Adam(self.env.parameters(), lr=self.cfg.lr_env)
        self.opt_nrm = torch.optim.Adam(self.normals.parameters(), lr=self.cfg.normals.lr) \
            if self.normals is not None else None

    @property
    def _normals_learn(self) -> bool:
        """Whether this step's shading normals learn (``normals.refine`` from
        ``normals.start``; never inside the materials' probe or the metalness race)."""
        return self.normals is not None and not self._racing and \
            self.step >= self.cfg.normals.start * self.cfg.iters

    def _sync_normals(self) -> None:
        """Put the learned normals (detached) into the geometry every render reads."""
        if self.normals is not None:
            with torch.no_grad():
                self.geom.vertex_normals = self.normals()

    def _cached_normals(self, idx: torch.Tensor) -> torch.Tensor:
        """(B, 3) shading normals at cached pixel-centre hits ``idx``: the cache's, or with
        ``normals.refine`` the current learned ones."""
        c = self.cache
        return c.n[idx] if self.normals is None else self.geom.normals_at(c.tri[idx],
                                                                          c.bary[idx])

    def _lr_factor(self) -> float:
        return self.cfg.lr_decay ** (self.step / max(self.cfg.iters, 1))

    def _maybe_upsample(self) -> None:
        if self.level + 1 < len(self.heights) and \
                self.step >= self.cfg.light.upsample_at * self.cfg.iters:
            self.level += 1
            self.env = self.env.upsampled(self.heights[self.level])
            self.opt_env = torch.optim.Adam(self.env.parameters(), lr=self.cfg.lr_env)
            self.log(f"[material] step {self.step}: env map -> {self.env.height} x "
                     f"{2 * self.env.height}")

    # ------------------------------------------------------------------ one step
    @property
    def jitter(self) -> bool:
        """Whether object pixels are rendered at a random point of their footprint."""
        c = self.cache
        return bool(self.cfg.render.jitter) and c.cam is not None and c.cameras is not None

    def render_pixels(self, idx: torch.Tensor, img: torch.Tensor,
                      indirect: IndirectLight | None, sampler) -> torch.Tensor:
        """Monte Carlo radiance of cached object pixels ``idx`` (linear, (B, 3)).

        With ``render.jitter`` each pixel is re-cast through a uniform random point of its
        footprint (the photos are box-filtered over it); a point that misses the mesh sees the
        env map. Otherwise the cached pixel-centre hit is shaded.
        """
        from voxnero.cameras.rays import pixel_rays

        c = self.cache
        if not self.jitter:
            return shade(self.geom, self.field, img, c.tri[idx], c.bary[idx], c.x[idx],
                         self._cached_normals(idx),
                         c.v[idx], self.spp, indirect, sampler, self.visibility, self.gen,
                         bounces=self.bounces, diffuse=self.cfg.render.diffuse)
        ci = idx.cpu()
        pix = c.pix[idx].cpu() + torch.rand(ci.shape[0], 2, generator=self.gen) - 0.5
        o, d = pixel_rays(c.cameras, c.cam[ci].cpu(), pix)
        _, tri, bary = self.geom.cast(o.to(self.device), d.to(self.device))
        d = d.to(self.device)
        h = (tri >= 0).nonzero()[:, 0]
        t, b = tri[h], bary[h]
        x, n = self.geom.points_at(t, b), self.geom.normals_at(t, b)
        lo = shade(self.geom, self.field, img, t, b, x, n, -d[h], self.spp, indirect, sampler,
                   self.visibility, self.gen, bounces=self.bounces,
                   diffuse=self.cfg.render.diffuse)
        return envmap_lookup(img, d).index_put((h,), lo)

    def loss_terms(self) -> dict[str, torch.Tensor]:
        """Losses of one random batch (object pixels, background pixels, priors)."""
        cfg, c = self.cfg, self.cache
        idx = torch.randint(0, c.x.shape[0], (min(cfg.batch, c.x.shape[0]),),
                            generator=self.gen).to(self.device)
        img = self.env.image()
        indirect = IndirectLight(img, diffuse=self.cfg.render.diffuse) \
            if self.use_indirect else None
        sampler = env_sampler(img) if self.spp.env else None
        normals = None
        if self._normals_learn:  # every render of this step reads them through the geometry
            normals = self.normals()
            self.geom.vertex_normals = normals
        if cfg.render.decorrelate:
            # two independent estimates of the same pixels (see decorrelated_loss)
            pred = self.render_pixels(torch.cat([idx, idx]), img, indirect, sampler)
            obj, mse = decorrelated_loss(pred, c.rgb[idx], self._linearised)
        else:
            pred = self.render_pixels(idx, img, indirect, sampler)
            obj = ((srgb_clipped(pred) - linear_to_srgb(c.rgb[idx])) ** 2).mean()
            mse = obj.detach()
        terms = {"object": obj}
        self._mse = float(mse)
        if cfg.bg_batch and c.bg_dirs.shape[0]:
            j = torch.randint(0, c.bg_dirs.shape[0], (cfg.bg_batch,),
                              generator=self.gen).to(self.device)
            bg = self.env.background(c.bg_dirs[j])
            terms["background"] = ((srgb_clipped(bg) - linear_to_srgb(c.bg_rgb[j])) ** 2).mean()
        fc = cfg.field
        w = self._smooth_weight()
        if w:
            terms["smooth"] = w * self.field.smoothness(generator=self.gen, norm=fc.smooth_norm)
        if fc.residual_l2:
            terms["residual"] = fc.residual_l2 * self.field.residual_penalty()
        if fc.range_prior:
            a, m, r = self.field(c.tri[idx], c.bary[idx], c.x[idx])
            terms["range"] = fc.range_prior * (m * (1 - m)).mean()
        if cfg.light.env_smooth:
            terms["env_smooth"] = cfg.light.env_smooth * self.env.smoothness()
        if normals is not None and cfg.normals.prior:
            terms["normal_prior"] = cfg.normals.prior * self.normals.prior(normals)
        return terms

    def _smooth_weight(self) -> float:
        """``field.smooth``; 0 inside the materials' probe (:meth:`_probe_features`)."""
        return 0.0 if self._probing else self.cfg.field.smooth

    @property
    def _linearised(self) -> bool:
        """Whether this step's object loss is the linearised one (``render.linearise_after``)."""
        after = self.cfg.render.linearise_after
        return after < 1 and self.step >= after * self.cfg.iters

    def _hold_brdf(self) -> None:
        """Zero the gradients of the metallic and roughness channels (raw channels 3 and 4 of
        every material parameter: the base (5,), per-vertex (V, 5) or grid (1, 5, R, R, R))."""
        for p in self.field.parameters():
            if p.grad is None:
                continue
            dim = 0 if p.dim() == 1 else 1
            p.grad.narrow(dim, 3, 2).zero_()

    def _maybe_split(self) -> None:
        """At ``field.split_at`` of the steps: one material or two (``field.regions``), then
        metalness per material by a race (``field.metal``)."""
        fc = self.cfg.field
        if self._racing or not isinstance(self.field, VertexMaterial) or \
                self.step != int(round(fc.split_at * self.cfg.iters)) or \
                self.field.split_done or self.field.metal_held:
            return
        regions = 1
        if fc.regions == "auto":
            feats = self._probe_features()
            sp = two_materials(feats, fc.split_distance, fc.split_min_fraction)
            c = sp.centres.cpu().tolist()
            self.decisions["material_regions"] = {
                "step": self.step, "regions": 2 if sp.accepted else 1,
                "distance": round(sp.distance, 4), "smaller_fraction": round(sp.fraction, 4),
                "centres_chromaticity_roughness": [[round(v, 3) for v in row] for row in c],
                "probe_steps": fc.probe_steps,
                "thresholds": {"distance": fc.split_distance,
                               "fraction": fc.split_min_fraction}}
            fmt = ["(" + ", ".join(f"{v:.2f}" for v in row) + ")" for row in c]
            verdict = "two materials: each gets its own base" if sp.accepted else \
                "one material"
            self.log(f"[material] step {self.step}: two-means of albedo chromaticity, roughness "
                     f"per vertex after a {fc.probe_steps}-step probe: "
                     f"centres {fmt[0]} / {fmt[1]}, {sp.distance:.3f} apart (>= "
                     f"{fc.split_distance:g}), smaller {100 * sp.fraction:.0f} % (>= "
                     f"{100 * fc.split_min_fraction:.0f} %) -> {verdict}")
            if sp.accepted:
                self.field.split(sp.labels, fc.split_metallic)
                regions = 2
        if fc.metal == "race":
            self._metal_race(regions)

    def _probe_features(self) -> torch.Tensor:
        """Per-vertex features for the two-materials question: albedo chromaticity (RGB / sum)
        and roughness (:func:`voxnero.material.regions.material_features`), read after
        ``field.probe_steps`` steps of a throw-away probe from the current state with the
        smoothness off and the light held: there the vertices show their own materials (the
        total variation that keeps a material piecewise constant also keeps two from showing
        apart: the corpus bunny's halves were 0.10 apart under 0.2, 0.30 under 0.05), and a
        light still being learned shows as brightness, which chromaticity ignores (the oak
        table's faces under its clipped panels: albedo 0.68 / 0.50 / 0.22 against 0.53 / 0.36
        / 0.17, the same hue)."""
        n = self.cfg.field.probe_steps
        start = self._state() if n else None
        if n:  # a fresh Adam: the kept one's second moments are the smoothness's, not the data's
            self.opt_mat = torch.optim.Adam(self.field.parameters(), lr=self.cfg.lr_material)
        self._racing, self._probing = True, True
        try:
            for _ in range(n):
                self.train_step()
            with torch.no_grad():
                feats = mesh_average(material_features(activated(self.field.raw)),
                                     self.field.edges, PROBE_AVERAGE_ROUNDS)
        finally:
            self._racing, self._probing = False, False
        if start is not None:
            self._restore(start)
        return feats

    def _metal_race(self, regions: int) -> None:
        """Decide metalness per material: every assignment of dielectric (0) / metal (1) to the
        ``regions`` materials trains ``field.race_steps`` steps from the same state with its
        metalness held; the one with the lowest object loss over the last third of its steps
        goes on (its steps count), held for the rest of the run. A metal that only imitates a
        rough dielectric under a light still being learned (or the reverse) loses here, where
        gradient descent from either side stayed in its basin (docs/STAGE2.md, session 20)."""
        n = self.cfg.field.race_steps
        start = self._state()
        results = []
        self._racing = True
        try:
            for combo in itertools.product((0.0, 1.0), repeat=regions):
                self._restore(start)
                self.field.hold_metal(combo)
                losses = [self.train_step()["object"] for _ in range(n)]
                tail = losses[-max(1, n // 3):]
                results.append((sum(tail) / len(tail), combo, self._state()))
        finally:
            self._racing = False
        best = min(results, key=lambda r: r[0])
        self._restore(best[2])
        name = {0.0: "dielectric", 1.0: "metal"}
        table = "; ".join(f"{'/'.join(name[v] for v in c)} {10 * math.log10(1 / max(l, 1e-12)):.2f}"
                          for l, c, _ in results)
        self.decisions["metal"] = {
            "step": self.step - n, "race_steps": n,
            "candidates": [{"metallic": list(c), "object_loss": round(l, 7)}
                           for l, c, _ in results],
            "held": list(best[1])}
        self.log(f"[material] step {self.step - n}: metalness race over {n} steps per candidate "
                 f"(object loss as dB, higher wins): {table} -> "
                 f"{'/'.join(name[v] for v in best[1])}")

    @torch.no_grad()
    def relabel_boundary(self, max_pixels: int = 16384) -> tuple[int, int]:
        """Place the boundary of a split field by the photos: every triangle touching it (a
        vertex shared with a triangle of the other material) takes the material whose render
        of its cached pixels (centre hits, twice the training samples, the same random numbers
        for both) is nearer the photo: sRGB error summed over its pixels, as the product of two
        independent estimates' errors, which has no Monte Carlo variance term (with one
        estimate the less noisy lobe would win); triangles no pixel sees keep theirs.

        Returns:
            (triangles changed, triangles considered).
        """
        f, c = self.field, self.cache
        if not isinstance(f, VertexMaterial) or not f.split_done:
            return 0, 0
        tris = self.geom.triangles.long()
        fr = f.face_region
        V = self.geom.n_vertices
        lo = torch.full((V,), 2, dtype=torch.long, device=fr.device)
        hi = torch.full((V,), -1, dtype=torch.long, device=fr.device)
        flat, lab = tris.reshape(-1), fr.repeat_interleave(3)
        lo.scatter_reduce_(0, flat, lab, "amin")
        hi.scatter_reduce_(0, flat, lab, "amax")
        band = (lo[tris] != hi[tris]).any(1)
        idx = band[c.tri].nonzero()[:, 0]
        if idx.numel() == 0:
            return 0, int(band.sum())
        if idx.numel() > max_pixels:
            idx = idx[torch.randperm(idx.numel(), generator=self.gen)[:max_pixels].to(idx.device)]
        img = self.env.image()
        indirect = IndirectLight(img, diffuse=self.cfg.render.diffuse) \
            if self.use_indirect else None
        sampler = env_sampler(img) if self.spp.env else None
        seed = int(torch.randint(0, 2**31 - 1, (1,), generator=self.gen))
        target = linear_to_srgb(c.rgb[idx])
        F = tris.shape[0]
        err = torch.zeros(2, F, device=fr.device)
        seen = torch.zeros(F, device=fr.device).index_add_(
            0, c.tri[idx], torch.ones(idx.shape[0], device=fr.device))
        keep = fr.clone()
        spp = Strategies(2 * self.spp.cos, 2 * self.spp.ggx, 2 * self.spp.env)
        for k in (0, 1):
            fr[band] = k
            e = torch.ones_like(target)
            for r in (0, 1):  # two independent estimates: (p1 - t)(p2 - t) has no variance term
                pred = torch.cat([
                    shade(self.geom, f, img, c.tri[j], c.bary[j], c.x[j],
                          self._cached_normals(j), c.v[j], spp,
                          indirect, sampler, self.visibility,
                          torch.Generator().manual_seed(seed + 2 * i + r),
                          bounces=self.bounces, diffuse=self.cfg.render.diffuse)
                    for i, j in enumerate(idx.split(4096))])
                e = e * (srgb_clipped(pred) - target)
            err[k].index_add_(0, c.tri[idx], e.mean(-1))
        new = torch.where(band & (seen > 0), (err[1] < err[0]).long(), keep)
        fr.copy_(new)
        return int((new != keep).sum()), int(band.sum())

    def _maybe_relabel(self) -> None:
        """Once the steps pass each of ``field.relabel_at`` (fractions of the steps; one that
        falls inside the metalness race is taken after it): up to :data:`RELABEL_PASSES` passes
        of :meth:`relabel_boundary` (the boundary moves by about a triangle per pass), until a
        pass changes under 1 % of the triangles along it."""
        fc = self.cfg.field
        if self._racing or not isinstance(self.field, VertexMaterial) or \
                not self.field.split_done:
            return
        due = [p for p in sorted({int(round(a * self.cfg.iters)) for a in fc.relabel_at})
               if self._relabel_from < p <= self.step]
        if not due:
            return
        self._relabel_from = self.step
        total, passes, band = 0, 0, 0
        while passes < RELABEL_PASSES:
            changed, band = self.relabel_boundary()
            total, passes = total + changed, passes + 1
            if changed <= 0.01 * band:
                break
        self.decisions.setdefault("boundary_relabel", []).append(
            {"step": self.step, "changed": total, "passes": passes, "band": band})
        self.log(f"[material] step {self.step}: material boundary placed by the photos: "
                 f"{total} triangles changed material in {passes} pass(es) ({band} along it now)")

    def train_step(self) -> dict[str, float]:
        """One optimisation step; returns the loss terms as floats."""
        self._maybe_upsample()
        self._maybe_split()
        self._maybe_relabel()
        f = self._lr_factor()
        opts = [(self.opt_mat, self.cfg.lr_material), (self.opt_env, self.cfg.lr_env)]
        if self.opt_nrm is not None:
            opts.append((self.opt_nrm, self.cfg.normals.lr))
        for opt, lr in opts:
            for g in opt.param_groups:
                g["lr"] = lr * f
        learn_normals = self._normals_learn
        terms = self.loss_terms()
        loss = sum(terms.values())
        for opt, _ in opts:
            opt.zero_grad(set_to_none=True)
        finite = bool(torch.isfinite(loss))
        if finite:
            loss.backward()
            params = [*self.field.parameters(), *self.env.parameters()]
            if learn_normals:
                params += list(self.normals.parameters())
            finite = all(bool(torch.isfinite(p.grad).all()) for p in params
                         if p.grad is not None)
        if finite:
            if self.cfg.render.hold_brdf and not self._linearised:
                self._hold_brdf()
            self.opt_mat.step()
            if isinstance(self.field, VertexMaterial):
                self.field.impose_metal()
            if not self._probing:
                self._env_step()
            if learn_normals:
                self.opt_nrm.step()
        else:  # never let one bad batch poison the parameters: skip the update
            for opt, _ in opts:
                opt.zero_grad(set_to_none=True)
        if learn_normals:
            self._sync_normals()
        self.guard.update(finite, self.step, last=self.step + 1 >= self.cfg.iters)
        self.step += 1
        out = {k: float(v.detach()) for k, v in terms.items()}
        out["loss"] = float(loss.detach())
        return out

    def _env_step(self) -> None:
        """Adam step of the env map; with ``light.update_smooth`` the step is blurred on the
        cells the photos never see directly (see LightConfig) and kept as is on the others."""
        sigma = float(self.cfg.light.update_smooth)
        p = self.env.log_radiance
        before = p.detach().clone() if sigma > 0 else None
        self.opt_env.step()
        if before is None:
            return
        H = int(p.shape[0])
        if self._unseen is None or self._unseen.shape[0] != H:
            cov = background_coverage(self.cache.bg_dirs, H)
            self._unseen = (cov == 0).float()[..., None].to(p.device)
        with torch.no_grad():
            step = p - before
            p.copy_(before + step + self._unseen * (latlong_blur(step, sigma) - step))

    def _nonfinite_cause(self) -> str:
        """The likely cause of a loss that stays non-finite (data first, then state)."""
        c = self.cache
        if nonfinite([("rgb", c.rgb), ("bg_rgb", c.bg_rgb)]):
            return "the training images hold NaN/Inf pixels (check the scene's image files)"
        if nonfinite([("x", c.x), ("n", c.n)]):
            return "the mesh has NaN/Inf vertices or degenerate triangles (check the mesh file)"
        bad = nonfinite([*self.field.named_parameters(), *self.env.named_parameters(),
                         *(self.normals.named_parameters() if self.normals is not None else [])])
        if bad:
            return (f"the {', '.join(bad[:3])} became NaN/Inf: lr_material={self.cfg.lr_material:g}"
                    f" or lr_env={self.cfg.lr_env:g} too high for this scene")
        return (f"the settings (lr_material={self.cfg.lr_material:g}, lr_env="
                f"{self.cfg.lr_env:g}, loss weights) or an env map that overflows")

    def material_medians(self, n: int = 4096) -> str:
        """Medians of metallic and roughness over (up to ``n``) cached surface points, for the
        log: how the material moves during training (e.g. a roughness sliding to its floor)."""
        c = self.cache
        k = min(n, c.x.shape[0])
        if k == 0:
            return "no surface points"
        idx = torch.linspace(0, c.x.shape[0] - 1, k).long().to(self.device)
        with torch.no_grad():
            _, m, r = self.field(c.tri[idx], c.bary[idx], c.x[idx])
        return f"metallic {float(m.median()):.3f}, roughness {float(r.median()):.3f} (medians)"

    # ------------------------------------------------------------------ loop
    def fit(self, ckpt: Path | None = None, progress: bool = True) -> dict[str, float]:
        """Train until ``cfg.iters`` steps (resuming from ``ckpt`` if it exists).

        Returns:
            Summary: final losses, steps, seconds.
        """
        from tqdm import tqdm

        if ckpt is not None and Path(ckpt).exists():
            self.load(ckpt)
            self.log(f"[material] resumed from {ckpt} at step {self.step}")
        t0 = time.perf_counter()
        start = self.step
        last: dict[str, float] = {}
        bar = tqdm(total=self.cfg.iters, initial=self.step, disable=not progress,
                   desc="material", dynamic_ncols=True, mininterval=1.0)
        ema = None
        with GracefulStop() as stop:
            while self.step < self.cfg.iters:
                before = self.step
                last = self.train_step()
                ema = self._mse if ema is None else 0.95 * ema + 0.05 * self._mse
                bar.update(self.step - before)  # the metalness race takes several at once
                if self.step % self.cfg.log_every == 0 or self.step == self.cfg.iters:
                    psnr = -10 * math.log10(max(ema, 1e-12))
                    bar.set_postfix(obj_psnr=f"{psnr:.2f}",
                                    bg=f"{last.get('background', 0):.2e}")
                    if not progress:
                        self.log(f"[material] step {self.step}/{self.cfg.iters} object "
                                 f"PSNR(ema) {psnr:.2f} dB, background mse "
                                 f"{last.get('background', 0):.2e}, "
                                 + self.material_medians())
                if ckpt is not None and self.cfg.checkpoint_every and \
                        self.step % self.cfg.checkpoint_every == 0:
                    self.save(ckpt)
                if stop.flag:  # Ctrl-C / SIGTERM during this step: it is complete now
                    bar.close()
                    if ckpt is not None:
                        self.save(ckpt)
                    self.log(f"[material] stopped at step {self.step}"
                             + ("; checkpoint saved, re-run the same command to resume"
                                if ckpt is not None else ""))
                    raise KeyboardInterrupt
        bar.close()
        if ckpt is not None and self.step > start:
            self.save(ckpt)
        self._report_normals()
        last["seconds"] = time.perf_counter() - t0
        last["steps"] = self.step
        return last

    def _report_normals(self) -> None:
        """Log how far the learned shading normals moved from the mesh's own and record it in
        the decisions (``materials.json``)."""
        if self.normals is None:
            self.decisions["normals"] = {"refined": False}
            return
        q = [float(v) for v in np.quantile(self.normals.angles_deg(), [0.5, 0.95, 1.0])]
        self.decisions["normals"] = {"refined": True, "from_step": int(math.ceil(
            self.cfg.normals.start * self.cfg.iters)), "change_deg_median": round(q[0], 3),
            "change_deg_p95": round(q[1], 3), "change_deg_max": round(q[2], 3)}
        self.log(f"[material] shading normals learned from step "
                 f"{self.decisions['normals']['from_step']}: {q[0]:.2f} deg from the mesh's "
                 f"own (median; 95 % within {q[1]:.2f}, max {q[2]:.1f}); exported with the mesh")

    # ------------------------------------------------------------------ checkpoints
    def fingerprint(self) -> dict:
        """What this run is made from: :attr:`sources` and the settings that shape the model."""
        return fingerprint.make(self.cfg, **self.sources)

    def save(self, path: Path) -> None:
        """Write a checkpoint (atomically).

        Raises:
            TrainingError: the parameters hold NaN/Inf (nothing written).
            RunFolderError: the checkpoint's folder was removed during the run.
        """
        path = Path(path)
        check_finite([*self.field.state_dict().items(), ("env", self.env.log_radiance),
                      *(self.normals.state_dict().items() if self.normals is not None else [])],
                     path, NONFINITE_FIX)
        if not path.parent.is_dir():
            raise RunFolderError("the run folder was removed during the run", path=path.parent,
                                 fix="re-run the command (into this --out it starts over)")
        state = {"fingerprint": self.fingerprint(), **self._state()}
        tmp = path.with_suffix(".tmp")
        torch.save(state, tmp)
        tmp.replace(path)

    def load(self, path: Path) -> None:
        """Restore a checkpoint written by :meth:`save`."""
        state = torch.load(path, map_location=self.device, weights_only=True)
        if not fingerprint.check_resume(state.get("fingerprint"), self.fingerprint(), path,
                                        "material"):
            self.log(f"[material] note: {path} predates run fingerprints; resuming without "
                     "checking its mesh, scene and settings")
        self._restore(state)
        self._relabel_from = self.step - 1
        if isinstance(self.field, VertexMaterial) and self.field.metal_held:
            self.decisions.setdefault("metal", {"held": self.field.metal_fixed.tolist(),
                                                "note": "restored from the checkpoint"})

    def _state(self) -> dict[str, Any]:
        """Everything training resumes from (copies, not references)."""
        state = {"step": self.step, "level": self.level,
                 "field": {k: v.detach().clone() for k, v in self.field.state_dict().items()},
                 "env": self.env.log_radiance.detach().clone(),
                 "opt_mat": copy.deepcopy(self.opt_mat.state_dict()),
                 "opt_env": copy.deepcopy(self.opt_env.state_dict()),
                 "gen": self.gen.get_state()}
        if self.normals is not None:
            state["normals"] = {k: v.detach().clone()
                                for k, v in self.normals.state_dict().items()}
            state["opt_nrm"] = copy.deepcopy(self.opt_nrm.state_dict())
        return state

    def _restore(self, state: dict[str, Any]) -> None:
        """Return to a :meth:`_state` (or a loaded checkpoint)."""
        self.step, self.level = int(state["step"]), int(state["level"])
        self.field.load_state_dict(state["field"])
        self.env = EnvLight.from_image(torch.exp(state["env"]).to(self.device), LOG_MAX, LOG_MIN)
        self._make_optimisers()
        self.opt_mat.load_state_dict(copy.deepcopy(state["opt_mat"]))
        self.opt_env.load_state_dict(copy.deepcopy(state["opt_env"]))
        if self.normals is not None and "normals" in state:
            self.normals.load_state_dict(state["normals"])
            self.opt_nrm.load_state_dict(copy.deepcopy(state["opt_nrm"]))
            self._sync_normals()
        self.gen.set_state(state["gen"].cpu())
