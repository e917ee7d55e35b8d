"""``voxnero batch``: reconstruct many scenes on Ray, one task per scene.

voxnero batch MANIFEST --preset NAME --out DIR [--address ADDR] [key=value ...]

MANIFEST is a folder of scene folders, or a YAML/CSV list of scenes with optional per-scene
overrides. Each scene runs 'voxnero reconstruct' (then 'voxnero eval' where the scene has ground
truth, a gt/ folder) as one Ray task into DIR/<scene>/. Without --address a local Ray is started
on this machine; --address HOST:6379 (or auto) joins a cluster made with 'ray start --head' and
'ray start --address HOST:6379'. Finished scenes are skipped on a re-run; a task whose worker dies
is retried and resumes from its checkpoint; a bad scene is an error row and does not stop the
others. Writes DIR/results.csv and DIR/results.md; the exit code is 0 only if every scene
succeeded (1 otherwise, 2 for a bad manifest or override).

Manifest as YAML (paths relative to the file; name and overrides optional):
  scenes:
    - scenes/sphere_gold
    - {path: /data/torus, name: torus, overrides: [shape.iters=3000]}
as CSV (overrides separated by spaces):
  path,name,overrides
  scenes/sphere_gold,,
  /data/torus,torus,shape.iters=3000 material.iters=800

Overrides name their section: shape.iters=3000, material.iters=800, eval.voxel=0.01,
batch.num_gpus=1 (batch keys: num_cpus, num_gpus, memory_mb, max_retries, command
(reconstruct|shape), eval, local_cpus, object_store_mb, dashboard, lock_timeout_s).
"""

from __future__ import annotations

import argparse

NAME = "batch"
HELP = "reconstruct many scenes on Ray (local or a cluster), with results.csv/results.md"
DESCRIPTION = __doc__.split("\n\n", 1)[1]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from voxnero.cli import add_common

    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    add_common(parser, "MANIFEST: folder of scene folders, or a .yaml/.csv list of scenes")
    parser.add_argument("--address", default=None,
                        help="Ray cluster to join (HOST:6379 or 'auto'); default: start a local "
                             "Ray on this machine")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    from voxnero.batch.runner import exit_code, run_batch

    rows = run_batch(args.target, args.preset, args.out, list(args.overrides),
                     address=args.address, device=args.device, progress=not args.no_progress)
    return exit_code(rows)
