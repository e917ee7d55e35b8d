"""``voxnero relight``: render an asset under another HDR environment map.

``voxnero relight ASSET_OR_RUN --env MAP.exr|.hdr --out DIR [--scene SCENE [--split NAME] |
--cameras transforms.json | --orbit] [--preset NAME] [key=value ...]``

ASSET_OR_RUN is a ``voxnero material`` output folder (model.glb / model.obj), a ``voxnero
reconstruct`` output folder (its ``material/``), a model file, or the ground truth of a scene
(``gt:SCENE`` or a scene folder with gt/mesh.ply + material.json).
Cameras: the ``relight.split`` split (default test) of ``--scene`` (or of the scene the asset
names), a ``transforms.json``, or a turntable (``--orbit``; ``relight.orbit.frames=36``,
``orbit.elevation_deg``, ``orbit.distance``, ``orbit.size``). Keys: ``spp``, ``dirs``,
``bounces``, ``tail``, ``scale`` (resolution), ``exposure`` (stops), ``yaw_deg`` (env rotation
about the up axis), ``views``, ``seed`` (section ``relight:`` of the preset).

Writes into ``--out`` (locked for the run; every file, ``config.yaml`` included, is replaced
only when the run succeeded, :mod:`voxnero.safety.folder`): ``<view>.png`` (sRGB,
round(255·sRGB(clip(L))) like the dev data), ``exr/<view>.exr`` (linear), ``config.yaml`` and
``relight.json`` (timings and, when the camera split has photos, PSNR against them: whole
image and fully covered pixels, raw and with a per-channel scale fitted on the object's
unclipped pixels). No output holds NaN/Inf: an env
map too bright for float32 at the given ``exposure`` is refused before rendering, a pixel that
still comes out non-finite is written as 0 with a warning (and counted in ``relight.json``), and
a non-finite number in ``relight.json`` is written as a string ("inf").
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

NAME = "relight"
HELP = "render an asset under another HDR environment map (PNG + EXR)"
DESCRIPTION = __doc__.split("\n\n", 1)[1]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from voxnero.cli import add_common

    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    add_common(parser, "run folder, model.glb / model.obj, or gt:SCENE")
    parser.add_argument("--env", required=True, help="equirectangular HDR map (.exr / .hdr)")
    cams = parser.add_mutually_exclusive_group()
    cams.add_argument("--scene", default=None, help="scene whose split gives the cameras")
    cams.add_argument("--cameras", default=None, help="a transforms.json giving the cameras")
    cams.add_argument("--orbit", action="store_true", help="turntable cameras (relight.orbit)")
    parser.add_argument("--split", default=None, help="split of --scene (default relight.split)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _cameras(args, cfg, asset):
    """(cameras (input frame), names, photos or None, where they came from)."""
    from voxnero.errors import ConfigError
    from voxnero.relight.cameras import orbit_cameras, scene_cameras, transforms_cameras

    if args.cameras:
        cams, names = transforms_cameras(args.cameras)
        return cams, names, None, str(args.cameras)
    if args.orbit:
        c, r = asset.bounds()
        o = cfg.orbit
        cams, names = orbit_cameras(c, r, asset.up, o.frames, o.elevation_deg, o.distance,
                                    o.fov_deg, o.size)
        return cams, names, None, "orbit"
    scene = args.scene or asset.scene
    if scene is None:
        raise ConfigError("no cameras: the asset names no scene",
                          fix="pass --scene SCENE, --cameras transforms.json or --orbit")
    split = args.split or cfg.split
    cams, names, photos = scene_cameras(scene, split)
    return cams, names, photos, f"{scene}:{split}"


def run(args: argparse.Namespace) -> int:
    import numpy as np
    import torch

    from voxnero.asset.load import load_asset
    from voxnero.config import resolve
    from voxnero.device import default_device
    from voxnero.relight.cameras import scaled
    from voxnero.relight.render import RelightConfig, load_env
    from voxnero.safety.folder import RunFolder

    cfg = resolve(RelightConfig, "relight", args.preset, args.overrides)
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    device = default_device(args.device)
    t0 = time.perf_counter()
    asset = load_asset(args.target)
    env = load_env(args.env, asset.up, cfg, device)
    cams, names, photos, cam_src = _cameras(args, cfg, asset)
    n = len(names)
    pick = list(range(n)) if cfg.views < 0 else \
        np.unique(np.linspace(0, n - 1, min(cfg.views, n)).round().astype(int)).tolist()
    cams_r = scaled(cams, cfg.scale)
    with RunFolder(args.out, "relight") as run:
        _render(args, cfg, device, asset, env, cams_r, names, photos, cam_src, pick, t0,
                run.staging)
        run.commit()
    return 0


def _render(args: argparse.Namespace, cfg: Any, device: Any, asset: Any, env: Any, cams_r: Any,
            names: list[str], photos: Any, cam_src: str, pick: list[int], t0: float,
            out: Path) -> None:
    """Render the views ``pick`` and write every output into ``out`` (the staging folder)."""
    import numpy as np
    import torch
    from tqdm import tqdm

    from voxnero.config import save_resolved
    from voxnero.eval.images import fit_channel_scale, psnr
    from voxnero.eval.report import json_safe
    from voxnero.io.color import linear_to_srgb
    from voxnero.io.exr import write_exr
    from voxnero.io.images import write_png
    from voxnero.relight.render import Relighter

    save_resolved(out, {"relight": cfg}, meta={
        "command": "relight", "asset": str(args.target), "env": str(args.env),
        "cameras": cam_src, "preset": args.preset, "overrides": list(args.overrides)})
    relighter = Relighter(asset, env, cfg, device)
    print(f"[relight] {asset.source}: {asset.triangles.shape[0]} triangles; env {args.env}; "
          f"{len(pick)} views of {cam_src} at {cams_r.width}x{cams_r.height}, {cfg.spp} spp x "
          f"{cfg.dirs} dirs, {cfg.bounces} bounce(s); load {time.perf_counter() - t0:.1f} s",
          flush=True)
    gen = torch.Generator().manual_seed(cfg.seed)
    bar = tqdm(total=len(pick) * cams_r.width * cams_r.height, unit="px", desc="relight",
               disable=args.no_progress)
    per_view, t1 = [], time.perf_counter()
    for i in pick:
        tv = time.perf_counter()
        r = relighter.render(cams_r, i, gen, progress=bar)
        rgb = r["rgb"].numpy()
        bad = ~np.isfinite(rgb).all(-1)
        if bad.any():  # never write NaN/Inf (load_env bounds the light; this is the last guard)
            rgb = np.where(bad[..., None], 0.0, rgb).astype(np.float32)
            bar.write(f"[relight] warning: view {names[i]}: {int(bad.sum())} pixel(s) with "
                      "NaN/Inf radiance written as 0", file=sys.stderr)
        srgb = np.asarray(linear_to_srgb(np.clip(rgb, 0.0, 1.0)))
        if cfg.png:
            write_png(out / f"{names[i]}.png", srgb)
        if cfg.exr:
            write_exr(out / "exr" / f"{names[i]}.exr", rgb.astype(np.float32), half=False)
        rec = {"view": names[i], "seconds": time.perf_counter() - tv,
               "coverage": float(r["alpha"].mean())}
        if bad.any():
            rec["nonfinite_pixels_zeroed"] = int(bad.sum())
        if photos is not None and cfg.scale == 1.0:
            gt = np.asarray(linear_to_srgb(np.clip(photos[i], 0.0, 1.0)))
            q = np.round(srgb * 255) / 255  # the 8-bit PNG as written
            full = r["alpha"].numpy() >= 1.0
            rec["psnr"] = psnr(q, gt)
            if full.any():
                rec["psnr_object"] = psnr(q, gt, full)
                # fit where neither side is clipped (a sun's reflection at L = 50 against an
                # 8-bit 1.0 would drive the least-squares scale toward 0)
                fit = full & (photos[i].max(-1) < 0.99)
                s = fit_channel_scale(rgb, photos[i], fit if fit.any() else full, clip=1.0)
                rec["psnr_object_scaled"] = psnr(
                    np.asarray(linear_to_srgb(np.clip(rgb * s, 0, 1))), gt, full)
        per_view.append(rec)
    bar.close()
    summary: dict = {"asset": asset.source, "env": str(args.env), "cameras": cam_src,
                     "views": per_view, "render_s": time.perf_counter() - t1,
                     "total_s": time.perf_counter() - t0}
    for k in ("psnr", "psnr_object", "psnr_object_scaled"):
        vals = [v[k] for v in per_view if k in v]
        if vals:
            summary[f"mean_{k}"] = float(np.mean(vals))
    (out / "relight.json").write_text(json.dumps(json_safe(summary), indent=1, allow_nan=False))
    msg = f"[relight] wrote {len(pick)} views to {args.out} in {summary['render_s']:.1f} s"
    if "mean_psnr" in summary:
        msg += (f"; vs {cam_src} photos: PSNR {summary['mean_psnr']:.2f} dB (object "
                f"{summary.get('mean_psnr_object', float('nan')):.2f} dB)")
    print(msg)
