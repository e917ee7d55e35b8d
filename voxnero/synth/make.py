"""``make_scene``: render an analytic scene and write it like the dev scenes.

Orchestration only (no physics): recipe → env map → cameras → per view path-traced radiance and
ground-truth maps → files. Each group of views traced together draws its noise from its own
seeded generator (``seed``, split, first view of the group), so a scene is reproducible
for a given config.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from voxnero.config import save_resolved
from voxnero.synth.camera_rig import fibonacci_dirs, focal_from_fov, look_at_opencv, offset_lattice
from voxnero.synth.config import SynthConfig
from voxnero.synth.envmaps import load_envmap
from voxnero.synth.materials import MaterialTable
from voxnero.synth.scenes import build_scene
from voxnero.synth.views import render_views
from voxnero.synth.writer import (
    folder_size,
    write_gt_maps,
    write_json,
    write_mesh,
    write_transforms,
    write_view,
)

_SPLIT_SEED = {"train": 0, "test": 1}


def _cameras(dirs: np.ndarray, cfg: SynthConfig):
    from voxnero.cameras.cameras import Cameras

    f = focal_from_fov(cfg.resolution, cfg.fov_deg)
    c = cfg.resolution / 2.0
    K = np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])
    c2w = look_at_opencv(cfg.distance * dirs)
    return Cameras(np.broadcast_to(K, (len(dirs), 3, 3)), c2w, cfg.resolution,
                   cfg.resolution), c2w, f


def make_scene(shape: str, out_dir: str | Path, cfg: SynthConfig | None = None,
               progress: bool = True, device: str | torch.device = "cpu") -> Path:
    """Render the analytic scene ``shape`` and write it to ``out_dir``.

    Args:
        shape: "sphere", "torus" or "two_spheres".
        out_dir: scene folder (created; existing files are overwritten).
        cfg: settings (default: :class:`SynthConfig` defaults, the standard size).
        progress: show a tqdm progress bar over views.
        device: torch device of the ray batches.

    Returns:
        The scene folder. It loads with ``voxnero.data.detect.load_scene``.
    """
    cfg = cfg or SynthConfig()
    cfg.validate()
    threads = torch.get_num_threads()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    try:
        return _make(shape, Path(out_dir), cfg, progress, device)
    finally:
        torch.set_num_threads(threads)


def _make(shape: str, out: Path, cfg: SynthConfig, progress: bool,
          device: str | torch.device) -> Path:
    from voxnero.render.envmap import EnvMap

    t_start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    geometry, mats, desc = build_scene(shape, cfg)
    table = MaterialTable.from_materials(mats)
    table = MaterialTable(table.albedo.to(device), table.metallic.to(device),
                          table.roughness.to(device))
    env_img, env_desc = load_envmap(cfg.env.source, cfg.env.height, cfg.env.seed,
                                    cfg.env.scale, cfg.env.constant)
    env = EnvMap(torch.as_tensor(env_img, device=device))

    # EnvMap.sample gathers one float64 CDF row (W values) per sample: keep that ≤ 512 MB
    chunk = min(cfg.chunk, max(4096, (512 << 20) // (8 * env_img.shape[1])))
    elev = (float(cfg.elevation_range_deg[0]), float(cfg.elevation_range_deg[1]))
    train_dirs = fibonacci_dirs(cfg.n_train, elev)
    test_dirs, rig_info = offset_lattice(cfg.n_test, train_dirs, elev, cfg.seed)
    splits = {"train": train_dirs, "test": test_dirs}
    timings: dict[str, float] = {}
    n_views = cfg.n_train + cfg.n_test
    bar = tqdm(total=n_views, desc=f"synth {shape}", unit="view", disable=not progress)
    for split, dirs in splits.items():
        t0 = time.perf_counter()
        cams, c2w, focal = _cameras(dirs, cfg)
        cams = cams.to(device)
        write_transforms(out, split, c2w, cfg.resolution, cfg.resolution, focal)
        group = max(1, chunk // (cfg.resolution ** 2 * cfg.spp))
        for g0 in range(0, len(dirs), group):
            views = list(range(g0, min(g0 + group, len(dirs))))
            gen = torch.Generator().manual_seed(
                (cfg.seed * 1_000_003 + _SPLIT_SEED[split]) * 100_003 + g0)
            imgs, maps = render_views(geometry, table, env, cams, views, cfg.spp,
                                      cfg.max_depth, gen, chunk)
            imgs = imgs.cpu().numpy()
            maps = {k: v.cpu().numpy() for k, v in maps.items()}
            for j, i in enumerate(views):
                write_view(out, split, i, imgs[j], maps["coverage"][j],
                           exr=(split == "test" or cfg.write_train_exr))
                if split == "test":
                    write_gt_maps(out, i, {k: v[j] for k, v in maps.items()})
            bar.update(len(views))
        timings[split] = round(time.perf_counter() - t0, 3)
    bar.close()

    t0 = time.perf_counter()
    from voxnero.io.exr import write_exr

    write_mesh(out / "gt" / "mesh.ply", *geometry.mesh_arrays())
    # half float like the dev scenes, unless the map is brighter than half's range (65504)
    write_exr(out / "gt" / "envmap.exr", env_img, half=bool(env_img.max() < 6e4))
    env_desc = dict(env_desc, file="gt/envmap.exr", resolution=[env_img.shape[1],
                                                                env_img.shape[0]])
    write_json(out / "gt" / "material.json", {
        "renderer": "voxnero.synth path tracer (exact ray-shape intersection, env-map NEE + "
                    f"BRDF sampling with MIS, max_depth {cfg.max_depth})",
        "bsdf": "voxnero.render.brdf.brdf_eval: Lambert (1-m) albedo/pi + GGX D, separable "
                "Smith G, Schlick F; F0 = 0.04 (1-m) + m albedo; alpha = roughness^2",
        **desc,
        "envmaps": {"train": env_desc},
        "envmap_mapping": "world dir d -> u = atan2(dx, dy)/(2pi) mod 1, v = arccos(dz)/pi; "
                          "col = u*W - 0.5, row = v*(H-1), bilinear (docs/ARCHITECTURE.md)",
        "world_up": "+Z",
    })
    timings["gt"] = round(time.perf_counter() - t0, 3)
    timings["total"] = round(time.perf_counter() - t_start, 3)
    save_resolved(out, {"synth": cfg}, meta={"command": "synth", "shape": shape})
    info = {"scene": shape, "split": "synth", "resolution": [cfg.resolution, cfg.resolution],
            "camera_angle_x": float(2.0 * np.arctan(0.5 * cfg.resolution / focal)),
            "fov_deg": cfg.fov_deg, "radius": cfg.distance, "elevation_range_deg": list(elev),
            "n_train": cfg.n_train, "n_test": cfg.n_test,
            "min_angle_test_to_train_deg": rig_info.get("min_angle_test_to_train_deg"),
            "test_lattice": rig_info,
            "spp": {"train": cfg.spp, "test": cfg.spp, "aov": cfg.spp},
            "max_depth": cfg.max_depth, "env": env_desc.get("kind"), "seed": cfg.seed,
            "bounding_radius": geometry.bounding_radius(), "timings_s": timings}
    write_json(out / "scene_info.json", info)
    info["size_bytes"] = folder_size(out)
    write_json(out / "scene_info.json", info)
    return out
