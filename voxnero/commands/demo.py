"""``voxnero demo``: the embedded default — make an analytic scene and run the pipeline on it.

Runs, as far as the stages exist: ``synth`` (a tiny analytic sphere scene) → ``shape``
(stage 1) → ``eval`` (Chamfer against the analytic truth) → ``material`` (stage 2). A stage that
is not built yet ends the demo with a plain message; nothing is faked. Re-running reuses what
is already there (each stage resumes or skips finished work).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from voxnero.errors import NotBuiltError

NAME = "demo"
HELP = "run the whole pipeline on an embedded analytic scene (no data needed)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="runs/demo", help="output folder (default: runs/demo)")
    parser.add_argument("--shape", default="sphere", help="analytic scene: sphere, torus, "
                        "two_spheres (default: sphere)")
    parser.add_argument("--preset", default="preview",
                        help="preset of the stages (default: preview)")
    parser.add_argument("--device", default="auto", help="auto (CUDA if available), cpu or cuda")


def _stage(argv: list[str]) -> None:
    from voxnero.cli import build_parser, parse_command_line

    args = parse_command_line(build_parser(), argv)
    rc = args._run(args)
    if rc:
        raise SystemExit(rc)


def run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    scene = out / f"scene_{args.shape}"
    steps = [
        ("synth", ["synth", args.shape, "--preset", "tiny", "--out", str(scene)]),
        ("shape", ["shape", str(scene), "--preset", args.preset, "--out", str(out / "shape"),
                   "--device", args.device]),
        ("eval", ["eval", str(out / "shape"), "--scene", str(scene), "--out", str(out / "eval")]),
        ("material", ["material", str(out / "shape"), "--preset", args.preset, "--out",
                      str(out / "material"), "--device", args.device]),
    ]
    for name, argv in steps:
        t0 = time.perf_counter()
        print(f"[demo] {name}: voxnero {' '.join(argv)}", flush=True)
        try:
            _stage(argv)
        except NotBuiltError as e:
            print(f"[demo] stopping before '{name}': {e}")
            return 0
        except SystemExit as e:  # argparse or a stage's non-zero exit code
            if e.code not in (0, None):
                raise
        print(f"[demo] {name} done in {time.perf_counter() - t0:.1f} s", flush=True)
    print(f"[demo] all stages done; outputs in {out}")
    return 0
