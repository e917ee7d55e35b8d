"""``voxnero material``: stage 2 — materials and lights on a fixed mesh, exported as an asset.

``voxnero material RUN_OR_MESH [--scene SCENE] --preset NAME --out DIR [key=value ...]``

RUN_OR_MESH is a stage-1 run folder (``mesh.ply`` in the input frame and ``config.yaml`` naming
the scene in ``_meta.scene``) or a mesh file in the scene's input frame (then ``--scene`` is
required). Writes into ``--out``: ``model.glb`` (+ ``model.glb.json``), ``model.obj`` / ``.mtl`` /
PNG textures, ``envmap.exr`` (+ ``envmap.json``), ``materials.json`` (statistics, decisions,
timings, metrics), ``config.yaml`` (resolved config), ``checkpoint.pt`` (re-running resumes;
another mesh, scene or other settings are refused unless ``--fresh``) and, if the scene has test
views, ``eval/`` comparison images. The folder is locked for the run and its outputs and
``config.yaml`` are replaced only when the run succeeded (:mod:`voxnero.safety.folder`).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

NAME = "material"
HELP = "stage 2: materials and env light on a fixed mesh -> model.glb, envmap.exr"
DESCRIPTION = __doc__.split("\n\n", 1)[1]
CKPT = "checkpoint.pt"
STATE = (CKPT, "checkpoint.tmp")
"""Run state of a stage-2 folder (``--fresh`` deletes it)."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from voxnero.cli import add_common, add_fresh

    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    add_common(parser, "stage-1 run folder (mesh.ply + config.yaml) or a mesh file (input "
               "frame; then --scene is required)")
    add_fresh(parser)
    parser.add_argument("--scene", default=None,
                        help="scene folder (default: _meta.scene of the run's config.yaml)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def locate(target: str | Path, scene: str | None) -> tuple[Path, Path]:
    """The mesh file and the scene folder a stage-2 run uses.

    Raises:
        DataError / ConfigError: no mesh, or no scene named anywhere.
    """
    from voxnero.config import read_meta
    from voxnero.errors import ConfigError, DataError

    p = Path(target)
    if p.is_dir():
        mesh = p / "mesh.ply"
        if not mesh.is_file():
            raise DataError("this folder holds no mesh.ply", path=p,
                            fix="pass a finished 'voxnero shape' run folder or a mesh file")
    elif p.is_file():
        mesh = p
    else:
        raise DataError("no such run folder or mesh file", path=p,
                        fix="pass a stage-1 run folder or a .ply/.obj mesh (input frame)")
    if scene:
        return mesh, Path(scene)
    meta = read_meta(mesh.parent)
    if meta.get("scene"):
        return mesh, Path(meta["scene"])
    raise ConfigError(f"no scene given for {p}", fix="pass --scene SCENE_FOLDER (the photos the "
                      "mesh was made from)")


def run(args: argparse.Namespace) -> int:
    import torch

    from voxnero.config import resolve
    from voxnero.material.config import MaterialConfig
    from voxnero.safety.folder import RunFolder

    cfg = resolve(MaterialConfig, "material", args.preset, args.overrides)
    if cfg.threads > 0:
        torch.set_num_threads(cfg.threads)
    mesh_path, scene_path = locate(args.target, args.scene)
    with RunFolder(args.out, "material", fresh=STATE if args.fresh else None) as run:
        _run(args, cfg, mesh_path, scene_path, run)
        run.commit()
    print(f"[material] wrote {run.path / 'model.glb'}, model.obj, envmap.exr, materials.json")
    return 0


def _run(args: argparse.Namespace, cfg: Any, mesh_path: Path, scene_path: Path,
         run: Any) -> None:
    """Train and write every output into ``run.staging`` (checkpoints into ``run.path``)."""
    import numpy as np
    import open3d as o3d
    import torch

    from voxnero.asset.envmap import write_envmap
    from voxnero.asset.gltf import diffuse_sidecar, write_glb
    from voxnero.asset.obj import write_obj
    from voxnero.asset.textures import bake_textures
    from voxnero.config import save_resolved
    from voxnero.data.detect import load_scene
    from voxnero.eval.images import psnr
    from voxnero.eval.report import json_safe
    from voxnero.io.color import linear_to_srgb
    from voxnero.io.exr import read_envmap
    from voxnero.material.evaluate import evaluate_scene
    from voxnero.material.field import surface_materials
    from voxnero.material.render import Strategies
    from voxnero.material.summary import vertex_areas, write_summary
    from voxnero.material.surface import Geometry, build_cache
    from voxnero.material.trainer import MaterialTrainer
    from voxnero.mesh.io import cut_mesh, load_mesh
    from voxnero.safety.fingerprint import file_digest, scene_digest

    out = run.staging
    save_resolved(out, {"material": cfg}, meta={
        "command": "material", "mesh": str(mesh_path), "scene": str(scene_path),
        "preset": args.preset, "overrides": list(args.overrides)})
    times = {}
    t0 = time.perf_counter()
    scene = load_scene(scene_path, splits=("train",))
    train = scene.split("train")
    from voxnero.shape.run_files import EXPOSURE

    gains_path = mesh_path.parent / EXPOSURE
    if gains_path.is_file():  # stage 1 measured the photos' exposures: undo them
        from voxnero.fields.exposure import read_gains

        gains = read_gains(gains_path, train.names)
        train.images = torch.as_tensor(train.images) / gains[:, None, None, :]
        lum = gains.mean(-1)
        print(f"[material] photos divided by stage 1's per-photo gains ({gains_path}: "
              f"{float(lum.min()):.2f}-{float(lum.max()):.2f}x)", flush=True)
    mesh = load_mesh(mesh_path, scene.norm)
    geom = Geometry.from_legacy(mesh)
    gen = torch.Generator().manual_seed(cfg.seed)
    cache = build_cache(geom, train.images, train.cameras, cfg.max_pixels, gen,
                        cfg.max_bg_pixels)
    times["load_and_cast_s"] = time.perf_counter() - t0
    print(f"[material] {scene_path}: {train.n} views; mesh {mesh_path} "
          f"({len(mesh.vertices)} vertices); object pixels {cache.n_object_total} "
          f"(kept {cache.x.shape[0]}), background {cache.n_background_total} "
          f"(kept {cache.bg_dirs.shape[0]}); {times['load_and_cast_s']:.1f} s", flush=True)
    if cache.x.shape[0] == 0:
        from voxnero.errors import DataError

        raise DataError("no training pixel sees the mesh", path=mesh_path,
                        fix="the mesh must be in the scene's input frame (as stage 1 writes it)")

    from voxnero.device import default_device

    device = default_device(args.device)
    trainer = MaterialTrainer(cfg, geom, cache, device=device,
                              sources={"scene": scene_digest(scene),
                                       "mesh": file_digest(mesh_path)})
    t1 = time.perf_counter()
    summary = trainer.fit(run.path / CKPT, progress=not args.no_progress)
    times["train_s"] = time.perf_counter() - t1
    print(f"[material] trained {trainer.step} steps in {times['train_s']:.1f} s", flush=True)

    # ---- exports (input frame)
    t2 = time.perf_counter()
    env = trainer.env.image().detach().cpu()
    vid, tris, a, m, r = (t.cpu() for t in surface_materials(trainer.field, trainer.geom))
    mesh_in = cut_mesh(load_mesh(mesh_path), vid.numpy(), tris.numpy())  # input frame
    if trainer.normals is not None:  # the learned shading normals (directions: any frame)
        mesh_in.vertex_normals = o3d.utility.Vector3dVector(
            trainer.geom.vertex_normals.detach().cpu().double().numpy()[vid.numpy()])
    tm = bake_textures(mesh_in, a.numpy(), m.numpy(), r.numpy(), cfg.texture_size)
    up = [float(x) for x in scene.up]
    write_glb(out / "model.glb", tm, sidecar={"scene_up": up, "scene": str(scene_path),
                                              **diffuse_sidecar(cfg.render.diffuse)})
    write_obj(out / "model.obj", tm)
    write_envmap(out / "envmap.exr", env.numpy(), extra={"scene_up": up,
                                                         "made_by": "voxnero material"})
    times["export_s"] = time.perf_counter() - t2

    # ---- checks: the exported env map reproduces the training background
    env_back = torch.from_numpy(read_envmap(out / "envmap.exr")).float()
    from voxnero.render.latlong import envmap_lookup

    bg_psnr = float("nan")
    if cache.bg_dirs.shape[0]:
        bg = envmap_lookup(env_back, cache.bg_dirs)
        bg_psnr = psnr(linear_to_srgb(bg.clamp(0, 1))[None, None],
                       linear_to_srgb(cache.bg_rgb)[None, None])
    print(f"[material] envmap.exr as background vs training background pixels: PSNR "
          f"{bg_psnr:.2f} dB", flush=True)

    metrics = {"background_psnr_train": bg_psnr, "train_loss": summary}
    if cfg.eval_views != 0:
        t3 = time.perf_counter()
        s = cfg.render.eval_scale
        spp = Strategies(cfg.render.spp_cos * s, cfg.render.spp_ggx * s, cfg.render.spp_env * s)
        metrics.update(evaluate_scene(scene_path, trainer.geom, trainer.field, env, spp,
                                      trainer.indirect_model, trainer.visibility,
                                      cfg.eval_views, out / "eval",
                                      subpixels=cfg.render.eval_subpixels,
                                      bounces=trainer.bounces,
                                      diffuse=cfg.render.diffuse))
        times["eval_s"] = time.perf_counter() - t3
    (out / "metrics.json").write_text(json.dumps(json_safe(metrics), indent=1, default=str,
                                                 allow_nan=False))
    w = vertex_areas(np.asarray(mesh_in.vertices), np.asarray(mesh_in.triangles))
    write_summary(out / "materials.json", a.numpy(), m.numpy(), r.numpy(), w, env.numpy(),
                  extra={"decisions": trainer.decisions, "times": times, "metrics": metrics,
                         "mesh": str(mesh_path), "scene": str(scene_path)})
    print(f"[material] outputs written (total {time.perf_counter() - t0:.0f} s)", flush=True)
