"""Stage-1 model and ray renderer: samples → SDF grid → NeuS weights → deferred shading.

Per ray (unit frame, ``o + t·d``):

1. clip to the bounding sphere (and to the SDF grid's box when the coarse stage fitted it to the
   object); a coarse no-grad pass of stratified samples gives NeuS weights and
   fine samples are drawn where the weight is (:mod:`voxnero.shape.sampler`);
2. the SDF grid returns value and analytic gradient at every sample; NeuS turns them into
   compositing weights ``w`` (:mod:`voxnero.shape.neus`);
3. **deferred shading**: the weight-averaged normal and position are shaded once per ray
   (split-sum GGX, :mod:`voxnero.shape.shading`) instead of at every sample; gradients still reach
   the SDF through ``w`` and the normals;
4. ``pixel = acc·surface + (1 − acc)·background``, background = env radiance along the ray
   (distant environment), a known colour (images with alpha), or a near-background field
   outside the unit sphere composited in front of the env map (:mod:`voxnero.fields.background`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import nn

from voxnero.fields.background import NearBackground
from voxnero.fields.exposure import ImageGains
from voxnero.fields.grid import DenseGrid, SDFGrid
from voxnero.fields.heads import MaterialHead
from voxnero.fields.lights import EnvLight, IndirectNet, OcclusionNet
from voxnero.render.brdf import safe_normalize
from voxnero.shape.config import ShapeConfig
from voxnero.shape.neus import (
    alpha_from_samples,
    alpha_from_sdf_sequence,
    alpha_from_sequence_min,
    composite_weights,
)
from voxnero.shape.sampler import clip_rays, interval_lengths, merge_sorted, sample_pdf, stratified
from voxnero.shape.shading import reflect, shade


@dataclass
class Switches:
    """Resolved model switches (the config's "auto" decided)."""

    indirect: bool = True
    occlusion: bool = True
    metallic: bool = True
    background: str = "distant"
    """"distant", "alpha" or "near"."""
    bg_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    exposure: bool = False
    """Per-photo gains on the renders of training pixels (:mod:`voxnero.fields.exposure`)."""


class ShapeModel(nn.Module):
    """All stage-1 parameters: SDF grid, feature grid, material head, lights.

    Args:
        cfg: the stage-1 config.
        sw: resolved switches.
        res: SDF grid resolution to build (defaults to the first of ``cfg.grid.res``).
        n_images: training photos; with ``light.exposure`` not "off" the model holds their
            gains (``gains``, identity until switched on: "auto" decides after the coarse stage).
    """

    def __init__(self, cfg: ShapeConfig, sw: Switches, res: int | None = None,
                 n_images: int = 0):
        super().__init__()
        g, lc = cfg.grid, cfg.light
        self.sw = sw
        self.diffuse = cfg.light.diffuse
        self.sdf = SDFGrid(res or g.res[0], g.bound, g.init_radius)
        self.feat = DenseGrid(g.feat_dim, g.feat_res, g.bound)
        nn.init.normal_(self.feat.grid, std=0.1)
        self.material = MaterialHead(g.feat_dim, lc.hidden, metallic=sw.metallic,
                                     init_roughness=lc.init_roughness)
        self.env = EnvLight(lc.env_height, lc.env_init, lc.max_log_radiance,
                            irradiance=lc.irradiance)
        self.indirect = IndirectNet(g.feat_dim, lc.hidden) if sw.indirect else None
        self.occlusion = OcclusionNet(g.feat_dim, lc.hidden) if sw.occlusion else None
        self.near_bg = (NearBackground(lc.near_res, lc.near_samples, lc.near_far_ratio)
                        if sw.background == "near" else None)
        self.gains = (ImageGains(n_images) if n_images > 0 and cfg.light.exposure != "off"
                      else None)

    def param_groups(self, cfg: ShapeConfig) -> list[dict]:
        """Adam parameter groups with their learning rates (named for schedules)."""
        o = cfg.optim
        groups = [dict(name="sdf", params=[self.sdf.grid], lr=o.lr_sdf),
                  dict(name="feat", params=[self.feat.grid], lr=o.lr_feat),
                  dict(name="heads", params=list(self.material.parameters()), lr=o.lr_heads),
                  dict(name="env", params=[self.env.log_radiance], lr=o.lr_env)]
        if self.near_bg is not None:
            groups.append(dict(name="near_bg", params=[self.near_bg.grid], lr=cfg.light.near_lr))
        if self.gains is not None:  # frozen (lr 0) until the switch is on
            groups.append(dict(name="gains", params=[self.gains.log_gain],
                               lr=cfg.light.exposure_lr if self.sw.exposure else 0.0))
        light = []
        for m in (self.indirect, self.occlusion):
            if m is not None:
                light += list(m.parameters())
        if light:
            groups.append(dict(name="light", params=light, lr=o.lr_light))
        return groups


def as_photographed(model: ShapeModel, rgb: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
    """Rendered linear RGB ``(R, 3)`` of pixels of training photos ``image`` (``(R,)`` long) as
    those photos recorded it: times the photo's gains when the exposure switch is on, else as
    is (held-out views always render as is, at the photos' mean exposure)."""
    if model.sw.exposure and model.gains is not None:
        return model.gains(rgb, image)
    return rgb


def background(model: ShapeModel, dirs: torch.Tensor, origins: torch.Tensor | None = None,
               train: bool = False, generator: torch.Generator | None = None) -> torch.Tensor:
    """Background radiance ``(R, 3)`` for rays ``origins + t·dirs`` (``(R, 3)``, unit frame,
    unit directions): the known colour, the env map along ``dirs``, or the near-background
    field outside the unit sphere in front of the env map (needs ``origins``)."""
    if model.sw.background == "alpha":
        return torch.tensor(model.sw.bg_color, device=dirs.device).expand(dirs.shape[0], 3)
    if model.near_bg is not None and origins is not None:
        rgb, trans = model.near_bg(origins, dirs, jitter=train, generator=generator)
        return rgb + trans[:, None] * model.env.background(dirs)
    return model.env.background(dirs)


def render_rays(model: ShapeModel, origins: torch.Tensor, dirs: torch.Tensor, s: float,
                cfg: ShapeConfig, train: bool = True, generator: torch.Generator | None = None,
                mark: Callable[[str], None] | None = None, coarse: int | None = None
                ) -> dict[str, torch.Tensor]:
    """Render a batch of rays.

    Args:
        model: the stage-1 model (call ``model.env.prepare()`` once per step before).
        origins: ``(R, 3)`` unit-frame ray origins; dirs: ``(R, 3)`` unit directions.
        s: NeuS sharpness.
        cfg: stage-1 config (sampling counts, normal mode).
        train: jitter samples (else deterministic).
        generator: RNG for the jitter.
        mark: optional profiler hook, called with a phase name at the end of each phase
            ("sampling", "grid", "neus", "heads", "shading"; see tools/bench_shape.py).
        coarse: coarse samples per ray instead of ``cfg.sampling.coarse``
            (:func:`voxnero.shape.schedules.coarse_samples`).

    Returns:
        dict with ``rgb (R, 3)`` linear radiance, ``acc (R,)``, ``normal (R, 3)`` (zero where no
        surface), ``hit (R,)`` bool, ``grad (M, 3)`` SDF gradients at all samples of hit rays (for
        the eikonal loss) and, for the hit rays only (index ``hit``): ``x (H, 3)`` surface point,
        ``refl (H, 3)``, ``occ (H, 1)`` predicted occlusion (if the net is on), ``acc_hit (H,)``.
    """
    mark = mark or (lambda name: None)
    sc = cfg.sampling
    r = origins.shape[0]
    dev = origins.device
    near, far, hit = clip_rays(origins, dirs, sc.radius, model.sdf.bounds)
    bg = background(model, dirs, origins, train, generator)
    rgb = bg.clone()
    acc_all = torch.zeros(r, device=dev)
    normal_all = torch.zeros(r, 3, device=dev)
    out: dict[str, torch.Tensor] = {"hit": hit}
    idx = torch.nonzero(hit).squeeze(-1)
    if idx.numel() == 0:
        out.update(rgb=rgb, acc=acc_all, normal=normal_all, grad=torch.zeros(0, 3, device=dev))
        return out
    o, d, n0, f0 = origins[idx], dirs[idx], near[idx], far[idx]
    # 1. coarse pass (no autograd) and fine samples
    with torch.no_grad():
        nc = sc.coarse if coarse is None else coarse
        zc = stratified(n0, f0, nc, jitter=train, generator=generator)
        sdf_c = model.sdf.sdf((o[:, None] + zc[..., None] * d[:, None]).reshape(-1, 3))
        w_c = composite_weights(alpha_from_sdf_sequence(sdf_c.view(zc.shape), zc, s))
        zf = sample_pdf(zc, w_c, sc.fine, jitter=train, generator=generator)
        step = max(nc // max(sc.coarse_keep, 1), 1)
        z = merge_sorted(zc[:, ::step][:, :sc.coarse_keep], zf)
    mark("sampling")
    # 2. SDF + gradient at the samples, NeuS weights
    pts = o[:, None] + z[..., None] * d[:, None]
    sdf, grad = model.sdf.sdf_grad(pts.reshape(-1, 3), cfg.grid.normals, cfg.grid.fd_step)
    sdf = sdf.view(z.shape)
    grad3 = grad.view(*z.shape, 3)
    mark("grid")
    if cfg.neus.alpha == "sequence":
        # opacity of the intervals between consecutive samples from their SDF values (and, with
        # neus.dip, their slopes along the ray, for a dip between two samples)
        if cfg.neus.dip:
            slope = (grad3 * d[:, None]).sum(-1)
            if cfg.neus.dip_detach:
                slope = slope.detach()
            w = composite_weights(alpha_from_sequence_min(sdf, slope, z, s))
        else:
            w = composite_weights(alpha_from_sdf_sequence(sdf, z, s))
        pts = 0.5 * (pts[:, 1:] + pts[:, :-1])
        grad3 = 0.5 * (grad3[:, 1:] + grad3[:, :-1])
    else:
        cos = (grad3 * d[:, None]).sum(-1)
        dists = interval_lengths(z, n0, f0)
        w = composite_weights(alpha_from_samples(sdf, cos, dists, s))
    acc = w.sum(-1)
    mark("neus")
    # 3. deferred shading at the weight-averaged point / normal
    n = safe_normalize((w[..., None] * safe_normalize(grad3)).sum(1))
    x = (w[..., None] * pts).sum(1) / acc.clamp(min=1e-6)[:, None]
    feat = model.feat(x)
    albedo, metallic, rough = model.material(feat)
    mark("heads")
    refl = reflect(d, n)
    spec = model.env.specular(refl, rough)
    occ = None
    if model.occlusion is not None:
        occ = model.occlusion(feat.detach(), refl.detach())
        if model.indirect is not None:
            ind = model.indirect(feat, refl, rough)
            spec = (1.0 - occ) * spec + occ * ind
    diff = model.env.diffuse(n)
    surf = shade(n, d, albedo, metallic, rough, spec, diff, model.diffuse)
    rgb = rgb.index_put((idx,), acc[:, None] * surf + (1.0 - acc[:, None]) * bg[idx])
    acc_all = acc_all.index_put((idx,), acc)
    normal_all = normal_all.index_put((idx,), n)
    mark("shading")
    out.update(rgb=rgb, acc=acc_all, normal=normal_all, grad=grad, x=x.detach(),
               refl=refl.detach(), n_hit=n.detach(), acc_hit=acc.detach(), hit_idx=idx,
               albedo=albedo, metallic=metallic, roughness=rough)
    if occ is not None:
        out["occ"] = occ
    return out
