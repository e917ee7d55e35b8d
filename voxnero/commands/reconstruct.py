"""``voxnero reconstruct``: stage 1 (``voxnero shape``) then stage 2 (``voxnero material``) with
one preset.

``voxnero reconstruct SCENE --preset NAME --out DIR [shape.key=value material.key=value ...]``

Writes ``DIR/shape/`` (mesh.ply, stage-1 run files) and ``DIR/material/`` (model.glb,
model.obj, envmap.exr, materials.json ...). Overrides must name their stage (``shape.iters=3000``,
``material.iters=800``); the region of interest and the masks switch of the scene,
``bbox=``, ``center=``, ``radius=`` and ``use_masks=``, may be given bare (they go to stage 1,
which writes the mesh in the input frame that stage 2 reads). Re-running resumes each stage from
its checkpoint (``--fresh``: both start over); each stage's folder is guarded as its own command
guards it (:mod:`voxnero.safety.folder`), and ``DIR`` is locked for the run.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

NAME = "reconstruct"
HELP = "stage 1 then stage 2 with one preset: photos -> mesh, materials, env light"
DESCRIPTION = __doc__.split("\n\n", 1)[1]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from voxnero.cli import add_common, add_fresh

    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    add_common(parser, "scene folder (NeRF-synthetic/Blender, NeRO or COLMAP)")
    add_fresh(parser)
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def _stage(argv: list[str]) -> None:
    from voxnero.cli import build_parser

    args = build_parser().parse_args(argv)
    rc = args._run(args)
    if rc:
        raise SystemExit(rc)


SCENE_KEYS = ("bbox", "center", "radius", "use_masks")
"""Overrides about the scene (region of interest, masks) accepted without a stage prefix."""


def split_overrides(items: list[str]) -> tuple[list[str], list[str]]:
    """Overrides for stage 1 and stage 2 (``shape.`` / ``material.`` prefixes kept).

    Raises:
        ConfigError: an override names no stage.
    """
    from voxnero.errors import ConfigError

    shape, material = [], []
    for item in items:
        key = item.split("=", 1)[0].strip()
        if key in SCENE_KEYS:
            shape.append(f"shape.{item.strip()}")
        elif key.startswith("shape."):
            shape.append(item)
        elif key.startswith("material."):
            material.append(item)
        else:
            raise ConfigError(f"override {item!r} does not name its stage",
                              fix=f"write shape.{item} or material.{item}")
    return shape, material


def run(args: argparse.Namespace) -> int:
    from voxnero.safety.folder import RunFolder

    ov_shape, ov_material = split_overrides(list(args.overrides))
    with RunFolder(args.out, "reconstruct") as run:  # the stages lock and guard their folders
        _stages(args, run.path, ov_shape, ov_material)
    return 0


def _stages(args: argparse.Namespace, out: Path, ov_shape: list[str],
            ov_material: list[str]) -> None:
    extra = ["--no-progress"] if args.no_progress else []
    extra += ["--fresh"] if args.fresh else []
    steps = [
        ("shape", ["shape", *extra, "--preset", args.preset, "--out", str(out / "shape"),
                   "--device", args.device, str(args.target), *ov_shape]),
        ("material", ["material", *extra, "--scene", str(args.target), "--preset", args.preset,
                      "--out", str(out / "material"), "--device", args.device,
                      str(out / "shape"), *ov_material]),
    ]
    for name, argv in steps:
        t0 = time.perf_counter()
        print(f"[reconstruct] {name}: voxnero {' '.join(argv)}", flush=True)
        _stage(argv)
        print(f"[reconstruct] {name} done in {time.perf_counter() - t0:.1f} s", flush=True)
    print(f"[reconstruct] outputs in {out}/shape and {out}/material")
