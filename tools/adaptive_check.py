#!/usr/bin/env python
"""Acceptance check of the adaptive stage-1 light model (issues #6, #7), end to end.

Renders the analytic scenes (``voxnero synth sphere|two_spheres --preset P``), trains stage 1 on
them adaptively and with the occlusion/indirect model forced, evaluates every mesh
(``voxnero eval``) and prints a table:

* single sphere (convex): the adaptive run must drop occlusion + indirect and be ≥ 30 % faster
  than the forced-on run at equal or better Chamfer;
* two spheres (they reflect each other): the adaptive run must keep them, and forcing them off
  must hurt Chamfer or PSNR.

``refl_hit`` is the self-occlusion the adaptive run measured on its carved surface (fraction of
reflected view rays that hit the object), ``refl_hit_gt`` the same on the ground-truth mesh.

Training time is the trainer's own (``shape.json`` ``train_time_s``, evaluation excluded).
PSNR is the training-batch PSNR (mean of the last 5 log records of ``log.jsonl``): stage-1 runs
have no test-view renders. Existing run folders are resumed (a finished run is not retrained);
use a fresh ``--work`` folder to re-measure. Runs are sequential: on a shared machine timings
move with the load, compare rows measured together.

Example::

    python tools/adaptive_check.py --work runs/adaptive_check
    python tools/adaptive_check.py --work /tmp/ac --parallel --extra   # + torus, other runs
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

RUNS = [("S1", "sphere", "adaptive", []),
        ("S1", "sphere", "forced_on", ["light.occlusion=on", "light.indirect=on"]),
        ("S2", "two_spheres", "adaptive", []),
        ("S2", "two_spheres", "forced_off", ["light.occlusion=off", "light.indirect=off"])]
EXTRA = [("S1", "sphere", "forced_off", ["light.occlusion=off", "light.indirect=off"]),
         ("S2", "two_spheres", "forced_on", ["light.occlusion=on", "light.indirect=on"]),
         ("T", "torus", "adaptive", []),
         ("T", "torus", "forced_off", ["light.occlusion=off", "light.indirect=off"])]
"""--extra: the other forced runs, and the analytic torus (self-occluding, 3.8 % of its
reflected view rays hit it, and stage 1 reconstructs it) to exercise the "on" branch."""


def _start(args: list[str], log: Path) -> subprocess.Popen:
    with open(log, "w") as fh:
        return subprocess.Popen([sys.executable, "-m", "voxnero", *args], stdout=fh,
                                stderr=subprocess.STDOUT)


def _wait(p: subprocess.Popen) -> None:
    if p.wait() != 0:
        raise SystemExit(f"{' '.join(p.args)} failed (exit {p.returncode})")


def _voxnero(args: list[str], log: Path) -> None:
    _wait(_start(args, log))


def _row(work: Path, scene: str, label: str) -> dict:
    run = work / f"{scene}_{label}"
    summ = json.loads((run / "shape.json").read_text())
    dec = json.loads((run / "decisions.json").read_text()) if \
        (run / "decisions.json").is_file() else {}
    met = json.loads((work / f"E_{scene}_{label}" / "metrics.json").read_text())
    logs = [json.loads(x) for x in (run / "log.jsonl").read_text().splitlines()]
    psnrs = [r["psnr"] for r in logs if "psnr" in r][-5:]
    occ = dec.get("occlusion", {})
    ev = occ.get("evidence", {})
    return {"scene": scene, "run": label, "occlusion": summ["switches"]["occlusion"],
            "indirect": summ["switches"]["indirect"],
            "decided_at": occ.get("step"), "refl_hit": ev.get("reflected_hit_fraction"),
            "train_s": round(summ["train_time_s"], 1), "chamfer": met["chamfer"]["cd"],
            "normal_deg": met.get("normals", {}).get("mean_deg"),
            "psnr": round(statistics.mean(psnrs), 2) if psnrs else None,
            "grid": summ["grid_res"], "background": summ["switches"]["background"]}


def gt_reflected_fraction(scene_dir: Path, n: int = 16384) -> float | None:
    """Self-occlusion of the ground-truth mesh (``gt/mesh.ply``) seen by the training cameras:
    what the adaptive measurement would find on a perfect reconstruction."""
    import numpy as np
    import open3d as o3d
    import torch

    from voxnero.cameras.rays import pixel_rays, random_pixels
    from voxnero.data.detect import load_scene
    from voxnero.shape.occlusion import reflected_hit_fraction

    path = scene_dir / "gt" / "mesh.ply"
    if not path.is_file():
        return None
    sc = load_scene(scene_dir, splits=("train",))
    mesh = o3d.io.read_triangle_mesh(str(path))
    mesh.vertices = o3d.utility.Vector3dVector(sc.norm.to_unit(np.asarray(mesh.vertices)))
    tr = sc.split("train")
    n_img, h, w = tr.images.shape[:3]
    cam, pix = random_pixels(n, n_img, h, w, generator=torch.Generator().manual_seed(0))
    o, d = pixel_rays(tr.cameras, cam, pix)
    return round(reflected_hit_fraction(mesh, o.double().numpy(), d.double().numpy())[0], 6)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", default="runs/adaptive_check", help="folder for scenes and runs")
    ap.add_argument("--preset", default="preview")
    ap.add_argument("--extra", action="store_true",
                    help="also sphere forced off and two_spheres forced on")
    ap.add_argument("--parallel", action="store_true",
                    help="train the runs of one scene at the same time (same machine load for "
                         "the timing comparison on a shared machine)")
    ap.add_argument("overrides", nargs="*", help="key=value for every shape run (e.g. iters=300)")
    a = ap.parse_args(argv)
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    runs = RUNS + (EXTRA if a.extra else [])
    for scene, shape in {(s, sh) for s, sh, _, _ in runs}:
        if not (work / scene / "transforms_train.json").is_file():
            print(f"synth {shape} -> {work / scene}", flush=True)
            _voxnero(["synth", shape, "--preset", a.preset, "--out", str(work / scene)],
                     work / f"synth_{scene}.log")
    gt_frac = {s: gt_reflected_fraction(work / s) for s in {r[0] for r in runs}}
    rows = []
    scenes = list(dict.fromkeys(r[0] for r in runs))
    groups = [[r for r in runs if r[0] == s] for s in scenes] if a.parallel \
        else [[r] for r in runs]
    for group in groups:
        procs = []
        for scene, _, label, ovr in group:
            print(f"shape {scene} {label} {' '.join(ovr)}", flush=True)
            procs.append(_start(["shape", str(work / scene), "--preset", a.preset, "--out",
                                 str(work / f"{scene}_{label}"), "--no-progress", *ovr,
                                 *a.overrides], work / f"shape_{scene}_{label}.log"))
        for p in procs:
            _wait(p)
        for scene, _, label, _ in group:
            _voxnero(["eval", str(work / f"{scene}_{label}"), "--scene", str(work / scene),
                      "--out", str(work / f"E_{scene}_{label}")],
                     work / f"eval_{scene}_{label}.log")
            rows.append({**_row(work, scene, label), "refl_hit_gt": gt_frac[scene]})
            print("  " + json.dumps(rows[-1]), flush=True)
    cols = ["scene", "run", "occlusion", "indirect", "decided_at", "refl_hit", "refl_hit_gt",
            "train_s",
            "chamfer", "normal_deg", "psnr", "grid", "background"]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(f"{r[c]:.5f}" if c == "chamfer" else
                                       f"{r[c]:.2f}" if c == "normal_deg" and r[c] else
                                       str(r[c]) for c in cols) + " |")
    by = {(r["scene"], r["run"]): r for r in rows}
    a1, f1 = by[("S1", "adaptive")], by[("S1", "forced_on")]
    a2, o2 = by[("S2", "adaptive")], by[("S2", "forced_off")]
    speed = f1["train_s"] / a1["train_s"] - 1.0
    checks = [
        ("S1 adaptive drops occlusion + indirect", not a1["occlusion"] and not a1["indirect"]),
        (f"S1 forced-on costs {speed:+.0%} time vs adaptive (need ≥ +30 %)", speed >= 0.30),
        (f"S1 Chamfer adaptive {a1['chamfer']:.5f} ≤ forced-on {f1['chamfer']:.5f}",
         a1["chamfer"] <= f1["chamfer"]),
        ("S2 adaptive keeps occlusion + indirect", a2["occlusion"] and a2["indirect"]),
        (f"S2 forced-off worse: Chamfer {o2['chamfer']:.5f} vs {a2['chamfer']:.5f}, PSNR "
         f"{o2['psnr']} vs {a2['psnr']}",
         o2["chamfer"] > a2["chamfer"] or (o2["psnr"] or 0) < (a2["psnr"] or 0)),
    ]
    lines += [""] + [f"- [{'x' if ok else ' '}] {text}" for text, ok in checks]
    table = "\n".join(lines)
    print("\n" + table)
    (work / "adaptive_check.md").write_text(table + "\n")
    (work / "adaptive_check.json").write_text(json.dumps({"rows": rows, "checks": [
        {"check": t, "ok": ok} for t, ok in checks]}, indent=2))
    return 0 if all(ok for _, ok in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
