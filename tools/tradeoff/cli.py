"""Measure the speed-accuracy trade of VoxNeRO's presets and knobs.

Each *point* is a preset plus optional ``key=value`` overrides (full keys: ``shape.*`` for stage
1, ``material.*`` for stage 2). For every scene and point the training command runs as its own
subprocess with one torch thread, then ``voxnero eval`` scores it:

- ``--stage shape``: ``voxnero shape SCENE --no-eval`` (timed), ``voxnero eval RUN``;
- ``--stage material``: the point's stage-1 run (made once per scene and stage-1 config, not
  timed), ``voxnero material RUN material.eval_views=0`` (timed), ``voxnero eval MATERIAL_DIR``;
- ``--stage both``: both training commands timed (the stage-1 run of equal stage-1 configs is
  shared between points and its time counted in each).

Recorded per run: wall time of the training command(s) (what the user waits for; the commands'
own in-training evaluations are switched off, ``voxnero eval`` is not counted), the trainers' own
clocks, peak RSS of the child (``os.wait4``), Chamfer, normal error and (stage 2) novel-view
PSNR. Written into ``--out``: ``tradeoff.csv`` (every run), ``tradeoff.md`` (median per point,
presets in bold) and ``tradeoff.png`` (time vs Chamfer and time vs PSNR). A run whose row is
already in the CSV is skipped, so an interrupted sweep continues where it stopped.

Examples::

    python -m tools.tradeoff --scenes /work/shared/data/sphere_gold \\
        /work/shared/data/torus_ceramic --out docs/tradeoff --jobs 2
    python -m tools.tradeoff --scenes S --out /tmp/t --points preview "standard shape.iters=800" \\
        shape.grid.res=[32,64]
    python -m tools.tradeoff --out docs/tradeoff --readme README.md     # tables from the CSV only
    python -m tools.tradeoff --check README.md --scenes S1 S2 --out /tmp/check --tolerance 0.2

``--points`` items: a preset name, a YAML spec file (``points: [{name, preset, overrides}]``,
see ``tools/tradeoff_configs/default.yaml``, the default), a single ``key=value`` (the ``--base``
preset with that override) or one quoted item ``"PRESET key=value key=value"``.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from tools.tradeoff.check import check, load_reference, render_check
from tools.tradeoff.points import DEFAULT_SPEC, REPO, Point, resolve_points
from tools.tradeoff.report import (
    is_done,
    read_csv,
    row_key,
    summarise,
    update_readme,
    write_outputs,
)
from tools.tradeoff.runner import Task, plan, sweep

STAGES = ("shape", "material", "both")


def _machine_note() -> str:
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, text=True,
                                capture_output=True, check=False).stdout.strip()
    except OSError:
        commit = ""
    return (f"Machine: {socket.gethostname()}, {os.cpu_count()} CPUs; written "
            f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
            + (f" at commit {commit}" if commit else "") + " by `python -m tools.tradeoff`.")


def _scene_map(scenes: Sequence[str]) -> dict[str, Path]:
    return {Path(s).resolve().name: Path(s).resolve() for s in scenes}


def main(argv: list[str] | None = None) -> int:
    """Command line; returns the exit code (1: ``--check`` out of tolerance or a run failed)."""
    ap = argparse.ArgumentParser(prog="python -m tools.tradeoff",
                                 description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=[], help="scene folders")
    ap.add_argument("--out", required=True, help="output folder (tradeoff.csv/.md/.png, runs/)")
    ap.add_argument("--points", nargs="+", default=None,
                    help="presets, key=value (on --base), \"PRESET k=v ...\" or YAML specs "
                         f"(default: {DEFAULT_SPEC.relative_to(REPO)})")
    ap.add_argument("--base", default="standard", help="preset of bare key=value points")
    ap.add_argument("--stage", choices=STAGES, default="shape", help="what is timed")
    ap.add_argument("--repeats", type=int, default=1, help="runs per point (median reported)")
    ap.add_argument("--jobs", type=int, default=1, help="points run at once")
    ap.add_argument("--timeout", type=float, default=None, help="seconds per child command")
    ap.add_argument("--check", default=None, metavar="TABLE",
                    help="re-run the points of a previous table (.md, README or .csv) into "
                         "--out (runs already there are reused: use a fresh folder) and "
                         "compare time and accuracy")
    ap.add_argument("--tolerance", type=float, default=0.2, help="relative, for --check")
    ap.add_argument("--readme", default=None,
                    help="put the table + image link between the tradeoff markers of this file")
    ap.add_argument("--list", action="store_true", help="print the runs and exit")
    args = ap.parse_args(argv)

    from voxnero.errors import VoxneroError

    try:
        return _main(args)
    except VoxneroError as e:
        print(f"tradeoff: error: {e}", file=sys.stderr)
        return 2


def _main(args: argparse.Namespace) -> int:
    from voxnero.errors import ConfigError, DataError

    out = Path(args.out)
    if args.repeats < 1 or args.jobs < 1:
        raise ConfigError("--repeats and --jobs must be >= 1")
    note = _machine_note()
    if args.check:
        ref = load_reference(Path(args.check))
        scenes = _scene_map(args.scenes)
        tasks = []
        for r in ref:
            path = scenes.get(r["scene"]) or (Path(r["scene_path"]) if r.get("scene_path")
                                               else None)
            if path is None or not path.is_dir():
                raise DataError(f"scene {r['scene']!r} of the table is not among --scenes",
                                path=args.check, fix=f"pass --scenes .../{r['scene']}")
            pt = Point(r["point"], r["preset"], tuple(r["overrides"].split()))
            tasks += [Task(path, pt, r["stage"], k) for k in range(args.repeats)]
        if args.list:
            for t in tasks:
                print(t.key())
            return 0
        before = {row_key(r) for r in read_csv(out / "tradeoff.csv") if is_done(r)}
        reused = sum(t.key() in before for t in tasks)
        if reused:
            print(f"[tradeoff] --check reuses {reused} finished run(s) already in {out} (an "
                  "interrupted check continues); pass a fresh --out to measure all anew")
        rows = sweep(tasks, out, args.jobs, args.timeout, note=note)
        results = check(ref, summarise(rows), args.tolerance)
        rep = render_check(results, args.tolerance)
        (out / "check.md").write_text(rep)
        print(rep)
        return 0 if all(c.ok for c in results) else 1

    rows: list[dict] = read_csv(out / "tradeoff.csv")
    if args.scenes:
        for s in args.scenes:
            if not Path(s).is_dir():
                raise DataError("no such scene folder", path=s)
        points = resolve_points(args.points, args.base)
        tasks = plan([Path(s).resolve() for s in args.scenes], points, args.stage, args.repeats)
        if args.list:
            for t in tasks:
                print(f"{t.scene.name:20s} {t.stage:9s} #{t.repeat}  {t.point.name:24s} "
                      f"{t.point.config}")
            return 0
        rows = sweep(tasks, out, args.jobs, args.timeout, note=note)
    elif not rows:
        raise ConfigError("nothing to do: no --scenes and no tradeoff.csv in --out",
                          fix="pass --scenes SCENE ... (and --points), or --out of a sweep")
    md = write_outputs(out, rows, note)
    print(md)
    if args.readme:
        update_readme(Path(args.readme), md, out / "tradeoff.png")
        print(f"[tradeoff] updated {args.readme}")
    failed = [r for r in rows if not is_done(r)]
    for r in failed:
        print(f"[tradeoff] {r['scene']} / {r['point']}: {r['status']}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
