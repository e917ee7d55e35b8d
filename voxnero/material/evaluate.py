"""Stage-2 renders of whole views and their metrics against held-out data.

A pixel's value is the box-filtered average of the radiance over its footprint, as the data's
renderer makes it (shared data README: Mitsuba ``box`` filter): each pixel is rendered at
``subpixels`` stratified jittered points (:func:`voxnero.cameras.rays.pixel_samples`), and
the pixel's Monte Carlo samples (:func:`voxnero.material.render.shade`, ``eval_scale`` × the
training samples) — one rotated Hammersley pattern per strategy — are dealt out among them, so
the cost does not grow and the pixel keeps the stratification of all its samples. Points that
hit the mesh are shaded, the others show the env map along the ray. Material maps and the hit
mask are read at pixel centres.

Metrics (``voxnero.eval.images``), in sRGB of the clipped linear render, as the 8-bit images
were made:

* novel views (``test``): PSNR / SSIM of the whole image and PSNR of fully covered pixels
  (mask = 1, evaluation-only masks);
* relighting (``test_relight_<env>`` with ``gt/envmap_<env>.exr``): the object under the new map,
  a per-channel scale fitted on linear values of fully covered pixels that are clipped neither in
  the 8-bit target nor in the scaled render (albedo–light ambiguity;
  :func:`voxnero.eval.images.fit_channel_scale` with ``clip=1``), PSNR / SSIM on the fully
  covered pixels;
* material maps: metallic and roughness MAE at fully covered test pixels vs
  ``gt/test_metallic``, ``gt/test_roughness``; albedo PSNR after a per-channel scale.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import torch

from voxnero.material.lights import IndirectLight
from voxnero.material.render import Bounces, Strategies, env_sampler, rotated_pattern, shade
from voxnero.material.surface import Geometry
from voxnero.render.latlong import envmap_lookup


def indirect_model(indirect: bool | str, geom: Geometry | None = None,
                   hits: tuple[torch.Tensor, torch.Tensor] | None = None) -> str:
    """The light model of secondary rays that hit the object: "traced", "splitsum" or "off".

    A string names the model; ``False`` is "off". ``True`` (what ``materials.json``'s
    ``decisions.indirect`` holds: "some indirect light") is decided as stage 2 decides it
    (:func:`voxnero.material.trainer.decide_secondary`) from the fraction of cosine rays from
    the visible surface points ``hits`` = (tri (M,), bary (M, 3)) that hit ``geom``: traced
    from ``TRACED_HIT_MIN``, else the split-sum estimate ("traced" without ``hits``).
    """
    if isinstance(indirect, str):
        if indirect not in ("traced", "splitsum", "off"):
            raise ValueError(f"unknown indirect model {indirect!r}")
        return indirect
    if not indirect:
        return "off"
    if geom is None or hits is None or hits[0].numel() == 0:
        return "traced"
    from types import SimpleNamespace

    from voxnero.material.trainer import TRACED_HIT_MIN, needs_indirect

    tri, bary = hits
    pts = SimpleNamespace(tri=tri, x=geom.points_at(tri, bary), n=geom.normals_at(tri, bary))
    frac = needs_indirect(geom, pts, generator=torch.Generator().manual_seed(0))
    return "traced" if frac >= TRACED_HIT_MIN else "splitsum"


def render_view(geom: Geometry, field, env_image: torch.Tensor, cameras, index: int,
                spp: Strategies, indirect: bool | str = True, visibility: bool = True,
                chunk: int = 2048, generator: torch.Generator | None = None,
                subpixels: int = 4, bounces: Bounces | None = None, diffuse: str = "weighted"
                ) -> dict[str, torch.Tensor]:
    """Render one view (linear radiance, box-filtered over each pixel) and its material maps.

    Args:
        geom: mesh (unit frame); field: material field; env_image: (H, W, 3) linear map.
        cameras: the views (unit frame); index: which one.
        spp: samples per strategy per pixel, dealt out among the subpixels from one rotated
            Hammersley pattern per pixel (sample j to subpixel j mod K, so the pixel keeps the
            stratification of all its samples; at most as many subpixels as the largest
            count); indirect: light along secondary rays that hit the object (see
            :func:`indirect_model`: True = traced inter-reflections, the stage-2 default);
            visibility: cast secondary rays.
        chunk: object pixels shaded at once.
        generator: torch generator (jitter and Monte Carlo).
        subpixels: points per pixel averaged in linear radiance (1: the pixel centre only).
        bounces: the traced model's bounces (default :class:`Bounces`()).
        diffuse: the BRDF's diffuse convention the material was fitted with
            (``voxnero.render.brdf.DIFFUSE_MODELS``; an asset's ``diffuse``).

    Returns:
        dict of ``rgb`` (H, W, 3) linear, ``hit`` (H, W) bool (pixel centre hits the mesh),
        ``albedo`` (H, W, 3), ``metallic`` (H, W), ``roughness`` (H, W) (at pixel centres, 0 on
        background).
    """
    from voxnero.cameras.rays import pixel_centers, pixel_rays, pixel_samples

    if subpixels < 1:
        raise ValueError(f"subpixels must be >= 1, got {subpixels}")
    H, W = int(cameras.height), int(cameras.width)
    dev = geom.device
    env_image = env_image.to(dev)
    centre = pixel_centers(H, W).reshape(-1, 2)
    cam = torch.full((H * W,), int(index), dtype=torch.long)
    if indirect is True:  # decided from this view's visible points, as stage 2 decides it
        o, d = pixel_rays(cameras, cam, centre)
        _, t0, b0 = geom.cast(o.to(dev), d.to(dev))
        model = indirect_model(True, geom, (t0[t0 >= 0], b0[t0 >= 0]))
    else:
        model = indirect_model(indirect)
    ind = IndirectLight(env_image, diffuse=diffuse) if model != "off" else None
    bnc = (bounces or Bounces()) if model == "traced" else None
    sampler = env_sampler(env_image) if spp.env else None
    counts = (spp.cos, spp.ggx, spp.env if sampler is not None else 0)
    subpixels = max(1, min(subpixels, max(counts)))
    # one rotated Hammersley pattern per pixel and strategy, dealt out to the subpixels
    # (sample j to subpixel j mod K): the pixel keeps the stratification of all its samples
    full = [rotated_pattern(H * W, c, generator) if c else None for c in counts]
    points = (centre[:, None] if subpixels == 1 else
              pixel_samples(H, W, subpixels, generator).reshape(H * W, subpixels, 2))
    rgb = torch.zeros(H * W, 3, device=dev)
    with torch.no_grad():
        for k in range(subpixels):
            pats = [p[:, k::subpixels] if p is not None else None for p in full]
            sub = Strategies(*(p.shape[1] if p is not None else 0 for p in pats))
            pats = [p if p is None or p.shape[1] else None for p in pats]
            o, d = pixel_rays(cameras, cam, points[:, k])
            o, d = o.to(dev), d.to(dev)
            _, tri, bary = geom.cast(o, d)
            c = envmap_lookup(env_image, d)
            idx = (tri >= 0).nonzero()[:, 0]
            for s in range(0, idx.shape[0], chunk):
                j = idx[s:s + chunk]
                t, b = tri[j], bary[j]
                x, n = geom.points_at(t, b), geom.normals_at(t, b)
                c[j] = shade(geom, field, env_image, t, b, x, n, -d[j], sub, ind, sampler,
                             visibility, generator,
                             [p[j.cpu()] if p is not None else None for p in pats], bnc,
                             diffuse)
            rgb += c / subpixels
        o, d = pixel_rays(cameras, cam, centre)
        _, tri, bary = geom.cast(o.to(dev), d.to(dev))
        hit = tri >= 0
        alb = torch.zeros(H * W, 3, device=dev)
        met = torch.zeros(H * W, device=dev)
        rough = torch.zeros(H * W, device=dev)
        idx = hit.nonzero()[:, 0]
        for s in range(0, idx.shape[0], chunk):
            j = idx[s:s + chunk]
            t, b = tri[j], bary[j]
            a, m, r = field(t, b, geom.points_at(t, b))
            alb[j], met[j], rough[j] = a, m[:, 0], r[:, 0]
    out = {"rgb": rgb.view(H, W, 3), "hit": hit.view(H, W), "albedo": alb.view(H, W, 3),
           "metallic": met.view(H, W), "roughness": rough.view(H, W)}
    return {k: v.cpu() for k, v in out.items()}


def render_converged(render: Callable[[], dict[str, torch.Tensor]], target: torch.Tensor,
                     mask: torch.Tensor, max_passes: int, noise_share: float = 0.1
                     ) -> tuple[dict[str, torch.Tensor], dict[str, float]]:
    """Average independent renders of one view until their Monte Carlo noise is a small share
    of the error against the photo, so that a score measures the model, not the estimator.

    After pass k >= 2 the noise variance of the mean image M is var_k(L) / k per pixel and
    channel (linear, unbiased sample variance across the passes), carried to sRGB by the
    encoding's slope (delta method; 0 where M >= 1, which the encoding clips):
    noise = mean over ``mask`` of g'(M)² var_k(L) / k. The error is the sRGB MSE of M against
    ``target`` over ``mask`` (it includes that noise). Passes stop when noise <= ``noise_share``
    × error (the noise then lowers the PSNR by at most −10 log10(1 − noise_share), 0.46 dB at
    0.1) or after ``max_passes``.

    Args:
        render: one independent render of the view (:func:`render_view`'s dict; each call
            draws new samples).
        target: (H, W, 3) linear photo.
        mask: (H, W) bool pixels scored.
        max_passes: at most this many renders (1: a single render, no noise estimate).
        noise_share: see above, in (0, 1).

    Returns:
        (the first render's dict with ``rgb`` replaced by the mean, info) with info
        ``passes``, ``noise_share`` (the last estimate, NaN after one pass) and ``noise_psnr``
        (10 log10(1 / noise), dB).
    """
    from voxnero.io.color import linear_to_srgb, srgb_slope

    first = render()
    if max_passes <= 1 or not mask.any():
        return first, {"passes": 1, "noise_share": float("nan"), "noise_psnr": float("nan")}
    s = first["rgb"].double()
    q = s ** 2
    k = 1
    share = noise = float("nan")
    g_t = linear_to_srgb(target.double().clamp(0, 1))[mask]
    while k < max_passes:
        r = render()["rgb"].double()
        s, q, k = s + r, q + r ** 2, k + 1
        mean = s / k
        var = ((q - k * mean ** 2) / (k - 1)).clamp_min(0.0)
        slope = torch.where(mean < 1, srgb_slope(mean), torch.zeros_like(mean))
        noise = float((slope ** 2 * var / k)[mask].mean())
        err = float(((linear_to_srgb(mean.clamp(0, 1))[mask] - g_t) ** 2).mean())
        share = noise / max(err, 1e-20)
        if share <= noise_share:
            break
    out = dict(first, rgb=(s / k).to(first["rgb"].dtype))
    return out, {"passes": k, "noise_share": share,
                 "noise_psnr": 10.0 * math.log10(1.0 / noise) if noise > 0 else float("inf")}


def _mean(xs: list[float]) -> float:
    xs = [min(x, 100.0) for x in xs if not math.isnan(x)]
    return float(np.mean(xs)) if xs else float("nan")


def evaluate_scene(scene_root: str | Path, geom: Geometry, field, env_image: torch.Tensor,
                   spp: Strategies, indirect: bool | str, visibility: bool = True,
                   views: int = -1, out_dir: str | Path | None = None,
                   log=print, subpixels: int = 4, bounces: Bounces | None = None,
                   passes: int = 1, noise_share: float = 0.1, diffuse: str = "weighted",
                   relight: bool = True) -> dict[str, Any]:
    """Novel-view, relighting and material-map metrics on a scene's test views.

    Args:
        scene_root: scene folder with ``transforms_test.json`` (and optionally relight splits,
            ``gt/``); cameras are loaded with the scene's own normalisation (must match the one
            the mesh was mapped with).
        geom, field, env_image: the fitted model (unit frame).
        spp: samples per strategy of the renders.
        indirect, visibility: as in :func:`render_view`.
        views: number of test views (evenly spread; -1 = all).
        out_dir: where to write comparison PNGs (``eval/``), or None.
        subpixels: points per pixel of the box filter (:func:`render_view`).
        bounces: the traced model's bounces (:func:`render_view`).
        passes, noise_share: each test view is the mean of up to ``passes`` independent
            renders of ``spp``, stopped once their noise is ``noise_share`` of the error in the
            scored pixels (:func:`render_converged`); its relit renders use as many passes.
        diffuse: the BRDF's diffuse convention (:func:`render_view`).
        relight: also render the relight splits (``res["relight"]`` stays empty without).

    Returns:
        Metrics dict (JSON-friendly); empty if the scene has no test split.
    """
    from voxnero.data.detect import available_splits, load_scene
    from voxnero.eval.images import fit_channel_scale, mae, psnr, ssim
    from voxnero.io.color import linear_to_srgb
    from voxnero.io.exr import read_envmap, read_exr
    from voxnero.io.images import write_png

    root = Path(scene_root)
    have = available_splits(root)
    if "test" not in have:
        return {}
    relights = [s for s in have if relight and s.startswith("test_relight_")
                and (root / "gt" / f"envmap_{s[len('test_relight_'):]}.exr").is_file()]
    scene = load_scene(root, splits=("test", *relights), eval_extras=True)
    test = scene.split("test")
    n_views = test.n if views < 0 else min(views, test.n)
    pick = np.unique(np.linspace(0, test.n - 1, n_views).round().astype(int)).tolist()
    out = Path(out_dir) if out_dir is not None else None
    gen = torch.Generator().manual_seed(1234)

    def srgb(x):
        return linear_to_srgb(x.clamp(0, 1))

    res: dict[str, Any] = {"views": pick, "spp": vars(spp), "subpixels": subpixels}
    nv = {"psnr": [], "ssim": [], "psnr_object": []}
    mat = {"metallic_mae": [], "roughness_mae": [], "albedo_psnr": []}
    renders = {}
    conv: dict[int, dict[str, float]] = {}
    for i in pick:
        gt = test.images[i]
        scored = ((test.masks[i] >= 1 - 0.5 / 255) if test.masks is not None
                  else torch.ones(gt.shape[:2], dtype=torch.bool))
        r, conv[i] = render_converged(
            partial(render_view, geom, field, env_image, test.cameras, i, spp, indirect,
                    visibility, generator=gen, subpixels=subpixels, bounces=bounces,
                    diffuse=diffuse),
            gt, scored, passes, noise_share)
        renders[i] = r
        pred = srgb(r["rgb"])
        nv["psnr"].append(psnr(pred, srgb(gt)))
        nv["ssim"].append(ssim(pred, srgb(gt)))
        full = (test.masks[i] >= 1 - 0.5 / 255) if test.masks is not None else r["hit"]
        full = full & r["hit"]
        if full.any():
            nv["psnr_object"].append(psnr(pred, srgb(gt), full))
        name = test.names[i]
        gtdir = root / "gt"
        if full.any() and (gtdir / "test_metallic" / f"{name}.exr").is_file():
            gm = torch.from_numpy(read_exr(gtdir / "test_metallic" / f"{name}.exr")[..., 0])
            gr = torch.from_numpy(read_exr(gtdir / "test_roughness" / f"{name}.exr")[..., 0])
            ga = torch.from_numpy(read_exr(gtdir / "test_albedo" / f"{name}.exr")[..., :3])
            mat["metallic_mae"].append(mae(r["metallic"], gm, full))
            mat["roughness_mae"].append(mae(r["roughness"], gr, full))
            s = fit_channel_scale(r["albedo"], ga, full)
            mat["albedo_psnr"].append(psnr(srgb(r["albedo"] * s), srgb(ga), full))
        if out is not None:
            write_png(out / f"test_{name}.png", torch.cat([pred, srgb(gt)], 1))
    res["novel_view"] = {k: _mean(v) for k, v in nv.items()}
    if passes > 1:  # the estimator's own noise, from the spread of the passes
        res["passes"] = {"per_view": [conv[i]["passes"] for i in pick],
                         "noise_share": [round(conv[i]["noise_share"], 4) for i in pick],
                         "noise_psnr_object": [round(conv[i]["noise_psnr"], 2) for i in pick]}
    res["materials"] = {k: _mean(v) for k, v in mat.items()}
    log(f"[material] test views: PSNR {res['novel_view']['psnr']:.2f} dB (object "
        f"{res['novel_view']['psnr_object']:.2f} dB), metallic MAE "
        f"{res['materials']['metallic_mae']:.3f}, roughness MAE "
        f"{res['materials']['roughness_mae']:.3f}")
    res["relight"] = {}
    for s in relights:
        env_name = s[len("test_relight_"):]
        sp = scene.split(s)
        env_new = torch.from_numpy(read_envmap(root / "gt" / f"envmap_{env_name}.exr")).float()
        vals = {"psnr": [], "ssim": []}
        for i in pick:
            r, _ = render_converged(
                partial(render_view, geom, field, env_new, sp.cameras, i, spp, indirect,
                        visibility, generator=gen, subpixels=subpixels, bounces=bounces,
                        diffuse=diffuse),
                sp.images[i], torch.ones(sp.images[i].shape[:2], dtype=torch.bool),
                conv[i]["passes"], 0.0)
            full = (test.masks[i] >= 1 - 0.5 / 255) if test.masks is not None else r["hit"]
            full = full & r["hit"]
            if not full.any():
                continue
            gt = sp.images[i]
            # fit the scale where neither the 8-bit target nor the scaled render is clipped (a
            # sun's reflection is hundreds of times brighter than 1 in the render and 1 in the
            # photo; a misplaced glint or a firefly would scale the whole view dark)
            unclipped = full & (gt.amax(-1) < 0.99)
            sc = fit_channel_scale(r["rgb"], gt, unclipped if unclipped.any() else full,
                                   clip=1.0)
            pred = srgb(r["rgb"] * sc)
            vals["psnr"].append(psnr(pred, srgb(gt), full))
            vals["ssim"].append(ssim(torch.where(full[..., None], pred, 0 * pred),
                                     torch.where(full[..., None], srgb(gt), 0 * pred), full))
            if out is not None:
                write_png(out / f"relight_{env_name}_{sp.names[i]}.png",
                          torch.cat([pred, srgb(gt)], 1))
        res["relight"][env_name] = {k: _mean(v) for k, v in vals.items()}
        log(f"[material] relight {env_name}: PSNR {res['relight'][env_name]['psnr']:.2f} dB "
            "(object, per-channel scale)")
    return res
