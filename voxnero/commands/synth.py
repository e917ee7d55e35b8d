"""``voxnero synth``: render an analytic test scene (sphere, torus, two spheres).

Writes the NeRF-synthetic layout of the dev scenes (images, masks, test EXRs, ground truth)
plus the resolved config. Example::

    voxnero synth torus --preset tiny --out /tmp/torus torus.tilt_deg=45 spp=32
"""

from __future__ import annotations

import argparse
import time

from voxnero.cli import add_common
from voxnero.config import resolve
from voxnero.errors import ConfigError
from voxnero.synth.config import SHAPES, SynthConfig

NAME = "synth"
HELP = "render an analytic test scene (sphere, torus, two_spheres) with ground truth"
DESCRIPTION = (HELP + ". Keys (synth section): resolution, n_train, n_test, spp, "
               "max_depth, seed, env.source (procedural|constant|FILE.exr), env.height, env.seed,"
               " sphere.radius, sphere.material.roughness, torus.tilt_deg, two_spheres.a.*, ...")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser, f"shape to render: {', '.join(SHAPES)}", default_preset="tiny")


def run(args: argparse.Namespace) -> int:
    from voxnero.device import default_device
    from voxnero.safety.folder import RunFolder
    from voxnero.synth.make import make_scene

    if args.target not in SHAPES:
        raise ConfigError(f"unknown synthetic shape {args.target!r}",
                          fix=f"use one of {', '.join(SHAPES)}")
    cfg = resolve(SynthConfig, "synth", args.preset, args.overrides)
    t0 = time.perf_counter()
    with RunFolder(args.out, "synth"):  # a usable folder, one writer at a time
        out = make_scene(args.target, args.out, cfg, progress=True,
                         device=default_device(args.device))
    print(f"synth {args.target}: {cfg.n_train} train + {cfg.n_test} test views at "
          f"{cfg.resolution}x{cfg.resolution}, {cfg.spp} spp in {time.perf_counter() - t0:.1f} s"
          f" -> {out}")
    return 0
