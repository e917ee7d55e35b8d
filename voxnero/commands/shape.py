"""``voxnero shape``: stage 1 — SDF geometry of a reflective object from posed photos.

Writes ``mesh.ply`` (input frame) and the run files described in
:mod:`voxnero.shape.run_files` into ``--out``. Re-running the same command resumes from the last
checkpoint (Ctrl-C or ``kill`` save one first); another scene or other settings are refused
unless ``--fresh``. The folder is locked for the run, and ``mesh.ply``, ``sdf.npz``,
``envmap.exr``, ``shape.json`` and ``config.yaml`` are replaced only when it succeeds
(:mod:`voxnero.safety.folder`).
"""

from __future__ import annotations

import argparse
import time

NAME = "shape"
HELP = "stage 1: SDF geometry (mesh.ply) from posed photos"
DESCRIPTION = ("Stage 1: reconstruct the geometry of a (shiny) object as a dense SDF grid with "
               "NeuS volume rendering and split-sum shading; writes mesh.ply in the input frame, "
               "checkpoints, previews and a log. Re-run the same command to resume.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from voxnero.cli import add_common, add_fresh

    add_common(parser, "scene folder (NeRF-synthetic/Blender, NeRO or COLMAP)",
               default_preset="standard")
    add_fresh(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--no-eval", action="store_true",
                        help="do not log Chamfer even if the scene has ground truth")


def _load(path: str, with_eval: bool, cfg=None):
    from voxnero.data.detect import load_scene
    from voxnero.errors import DataError

    roi = {} if cfg is None else dict(bbox=cfg.bbox, center=cfg.center, radius=cfg.radius,
                                      masks_as_alpha=cfg.use_masks)
    if with_eval:
        try:
            return load_scene(path, splits=("train", "test"), eval_extras=True, **roi)
        except DataError:
            pass
    return load_scene(path, splits=("train",), **roi)


def run(args: argparse.Namespace) -> int:
    from voxnero.config import resolve, save_resolved
    from voxnero.device import default_device
    from voxnero.safety.folder import RunFolder
    from voxnero.shape.config import ShapeConfig
    from voxnero.shape.run_files import STATE
    from voxnero.shape.trainer import ShapeTrainer

    cfg = resolve(ShapeConfig, "shape", args.preset, args.overrides)
    device = default_device(args.device)
    with RunFolder(args.out, "shape", fresh=STATE if args.fresh else None) as run:
        t0 = time.perf_counter()
        scene = _load(args.target, not args.no_eval, cfg)
        print(f"[shape] loaded {args.target} in {time.perf_counter() - t0:.1f} s; device "
              f"{device}", flush=True)
        save_resolved(run.staging, {"shape": cfg},
                      meta={"command": "shape", "scene": str(args.target),
                            "preset": args.preset, "overrides": list(args.overrides)})
        trainer = ShapeTrainer(cfg, scene, run.path, device=device,
                               progress=not args.no_progress, outputs=run.staging)
        trainer.run()
        run.commit()
    print(f"[shape] wrote {run.path / 'mesh.ply'} ({trainer.train_time:.0f} s of training, "
          f"{trainer.step} steps)")
    return 0
