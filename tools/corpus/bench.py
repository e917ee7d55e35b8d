#!/usr/bin/env python
"""Measure VoxNeRO's presets on the corpus: Chamfer in pixels, normal error, genus, relight PSNR.

The runs themselves are ``tools/tradeoff/``'s (one child process per training command, one
torch thread, ``--stage both``: ``voxnero shape`` then ``voxnero material``, both timed, then
``voxnero eval`` on the stage-2 output); this script adds what the corpus needs on top of its
CSV and run folders:

- Chamfer in pixels: the NeRO Chamfer (scene frame) over the scene's pixel footprint at the
  origin (``scene_info.json`` ``pixel_size``: the camera distance varies with the fill); and the
  same against the true mesh at the pixel centres (``voxnero eval``'s ``chamfer_exact``: the
  stored depth is a pixel average with points in mid-air at depth edges, which flatters a lid
  over a cavity; :mod:`voxnero.eval.chamfer`);
- genus of the reconstructed mesh's largest component against the truth (``None``: that
  component is not a closed 2-manifold), and its number of components;
- relight PSNR: mean over the scene's two relight maps of ``voxnero eval``'s object PSNR with
  the per-channel scale fit;
- per preset, the median and the worst scene.

Writes ``corpus.csv`` and ``corpus.md`` into ``--out``. A finished run is not repeated (the
sweep resumes from ``tradeoff.csv``).

Examples::

    python -m tools.corpus.bench --corpus cache/corpus --out cache/bench --jobs 2
    python -m tools.corpus.bench --corpus cache/corpus --out cache/bench --report-only
"""

from __future__ import annotations

import argparse
import csv
import math
import statistics
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from tools import tradeoff  # noqa: E402
from voxnero.batch.process import read_json  # noqa: E402
from voxnero.mesh.topology import mesh_topology  # noqa: E402

COLUMNS = ["scene", "preset", "stage", "status", "time_s", "shape_s", "material_s", "chamfer",
           "chamfer_px", "chamfer_exact_px", "normal_deg", "genus", "genus_true", "components",
           "psnr_object", "relight_psnr", "pixel_size"]


def run_dirs(out: Path, scene: str, preset: str) -> tuple[Path, Path]:
    """The stage-1 and stage-2 folders ``tools/tradeoff/`` made for (scene, preset)."""
    p = tradeoff.parse_point(preset)
    cfg = " ".join((p.preset, *p.for_stage("shape")))
    base = out / "runs" / scene
    return (base / f"shape-{tradeoff._slug(cfg)}" / "r0",
            base / f"material-{tradeoff._slug(p.config)}" / "r0")


def collect(corpus: Path, out: Path) -> list[dict]:
    """One row per (scene, preset) of ``out/tradeoff.csv``, with the corpus metrics added."""
    rows = []
    csv_rows = tradeoff.read_csv(out / "tradeoff.csv")
    def point(r: dict) -> str:  # the preset with its overrides: what names the run folders
        return r.get("point") or r["preset"]

    both = {(r["scene"], point(r)) for r in csv_rows
            if r["stage"] == "both" and tradeoff.is_done(r)}
    for r in csv_rows:
        if r["stage"] != "both" and (r["scene"], point(r)) in both:
            continue  # the same stage-1 run, measured with stage 2 too
        scene = Path(r["scene_path"]) if r.get("scene_path") else corpus / r["scene"]
        info = read_json(scene / "scene_info.json")
        px = float(info.get("pixel_size", "nan"))
        sdir, mdir = run_dirs(out, r["scene"], point(r))
        metrics = read_json(mdir / "eval" / "metrics.json")
        exact = (read_json((mdir if r["stage"] == "both" else sdir) / "eval" / "metrics.json")
                 .get("chamfer_exact") or {}).get("cd", math.nan)
        relight = [v.get("psnr", math.nan) for v in (metrics.get("relight") or {}).values()]
        genus, comps = (mesh_topology(sdir / "mesh.ply") if (sdir / "mesh.ply").is_file()
                        else (None, 0))
        ch = tradeoff._num(r["chamfer"])
        rows.append({
            "scene": r["scene"], "preset": r["preset"], "stage": r["stage"],
            "status": r["status"],
            "time_s": tradeoff._num(r["time_s"]), "shape_s": tradeoff._num(r["shape_s"]),
            "material_s": tradeoff._num(r["material_s"]), "chamfer": ch,
            "chamfer_px": ch / px if px > 0 else math.nan,
            "chamfer_exact_px": exact / px if px > 0 else math.nan,
            "normal_deg": tradeoff._num(r["normal_deg"]), "genus": genus,
            "genus_true": info.get("genus"), "components": comps,
            "psnr_object": (metrics.get("novel_view") or {}).get("psnr_object", math.nan),
            "relight_psnr": statistics.fmean(relight) if relight else math.nan,
            "pixel_size": px})
    return rows


def _f(v: object, digits: int = 2) -> str:
    if v is None:
        return "open"
    if isinstance(v, float):
        return "—" if math.isnan(v) else f"{v:.{digits}f}"
    return str(v)


def summary(rows: list[dict]) -> list[dict]:
    """Per preset: median and worst scene of Chamfer (px), normal error, relight PSNR, time;
    how many scenes with holes got the right genus."""
    out = []
    for preset in dict.fromkeys(r["preset"] for r in rows):
        rs = [r for r in rows if r["preset"] == preset and r["status"] == "ok"]
        if not rs:
            continue

        def med(k, rs=rs):
            v = [r[k] for r in rs if not math.isnan(r[k])]
            return statistics.median(v) if v else math.nan

        worst = max(rs, key=lambda r: r["chamfer_px"] if not math.isnan(r["chamfer_px"])
                    else math.inf)
        holes = [r for r in rs if (r["genus_true"] or 0) > 0]
        out.append({"preset": preset, "scenes": len(rs), "chamfer_px_median": med("chamfer_px"),
                    "chamfer_px_worst": worst["chamfer_px"], "worst_scene": worst["scene"],
                    "chamfer_exact_px_median": med("chamfer_exact_px"),
                    "chamfer_exact_px_worst": max((r["chamfer_exact_px"] for r in rs
                                                   if not math.isnan(r["chamfer_exact_px"])),
                                                  default=math.nan),
                    "normal_deg_median": med("normal_deg"),
                    "normal_deg_worst": max(r["normal_deg"] for r in rs),
                    "relight_psnr_median": med("relight_psnr"),
                    "relight_psnr_worst": min((r["relight_psnr"] for r in rs
                                               if not math.isnan(r["relight_psnr"])),
                                              default=math.nan),
                    "shape_s_median": med("shape_s"),
                    "shape_s_worst": max(r["shape_s"] for r in rs),
                    "genus_right": f"{sum(r['genus'] == r['genus_true'] for r in holes)}"
                                   f" / {len(holes)}"})
    return out


def markdown(rows: list[dict], note: str = "") -> str:
    """Per-scene table and the per-preset summary, as Markdown."""
    lines = ["| scene | preset | Chamfer (px) | Chamfer | at the true mesh (px) | normal error | "
             "genus (truth) | "
             "components | relight PSNR (object) | novel-view PSNR (object) | wall time stage 1 "
             "+ 2 |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(rows, key=lambda r: (r["preset"], r["scene"])):
        if r["status"] != "ok":
            lines.append(f"| {r['scene']} | `{r['preset']}` | {r['status']} |||||||||")
            continue
        lines.append(
            f"| {r['scene']} | `{r['preset']}` | {_f(r['chamfer_px'])} | "
            f"{_f(r['chamfer'], 4)} | {_f(r['chamfer_exact_px'])} | "
            f"{_f(r['normal_deg'], 1)}° | {_f(r['genus'])} "
            f"({r['genus_true']}) | {r['components']} | {_f(r['relight_psnr'])} dB | "
            f"{_f(r['psnr_object'])} dB | {_f(r['shape_s'], 0)} + "
            f"{_f(r['material_s'], 0)} s |")
    lines += ["", "| preset | scenes | Chamfer median / worst (px) | worst scene | at the true "
              "mesh median / worst (px) | normal error median / worst | right genus (scenes with "
              "holes) | relight PSNR median / worst | stage-1 wall time median / worst |",
              "|---|---|---|---|---|---|---|---|---|"]
    for s in summary(rows):
        lines.append(
            f"| `{s['preset']}` | {s['scenes']} | {_f(s['chamfer_px_median'])} / "
            f"{_f(s['chamfer_px_worst'])} | {s['worst_scene']} | "
            f"{_f(s['chamfer_exact_px_median'])} / {_f(s['chamfer_exact_px_worst'])} | "
            f"{_f(s['normal_deg_median'], 1)}° / {_f(s['normal_deg_worst'], 1)}° | "
            f"{s['genus_right']} | {_f(s['relight_psnr_median'])} / "
            f"{_f(s['relight_psnr_worst'])} dB | {_f(s['shape_s_median'], 0)} / "
            f"{_f(s['shape_s_worst'], 0)} s |")
    return "\n".join(lines) + ("\n\n" + note if note else "") + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corpus", type=Path, required=True, help="folder of tools.corpus.build")
    ap.add_argument("--out", type=Path, required=True, help="sweep and report folder")
    ap.add_argument("--scenes", nargs="*", help="scene names (default: every scene built)")
    ap.add_argument("--points", nargs="+", default=["preview", "standard"],
                    help="presets (and overrides) as python -m tools.tradeoff takes them")
    ap.add_argument("--stage", choices=("shape", "both"), default="both",
                    help="shape: stage 1 only (no relight PSNR); both: stage 1 and 2")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--report-only", action="store_true", help="no runs: tables from the CSV")
    args = ap.parse_args(argv)
    names = args.scenes or sorted(p.parent.name for p in args.corpus.glob("*/scene_info.json"))
    if not names:
        print(f"error: no finished scene in {args.corpus}; build it first with "
              "python -m tools.corpus.build --out DIR", file=sys.stderr)
        return 2
    rc = 0
    if not args.report_only:
        rc = tradeoff.main(["--scenes", *[str(args.corpus / n) for n in names], "--out",
                            str(args.out), "--points", *args.points, "--stage", args.stage,
                            "--jobs", str(args.jobs)])
    rows = [r for r in collect(args.corpus, args.out) if r["scene"] in names]
    with open(args.out / "corpus.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        w.writerows(rows)
    md = markdown(rows, tradeoff._machine_note())
    (args.out / "corpus.md").write_text(md)
    print(md)
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
