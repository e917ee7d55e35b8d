"""``voxnero eval``: score a mesh against a scene's ground truth.

``voxnero eval RUN_OR_MESH --scene SCENE --out DIR [key=value ...]``

RUN_OR_MESH is a run folder holding ``mesh.ply`` (written in the scene's input frame by
``voxnero shape``) or a mesh file in the input frame. SCENE is a scene with evaluation data
(``test_mask/`` and ``gt/test_depth/``, optionally ``gt/test_normal/``), e.g. a dev scene or one
made by ``voxnero synth``; without ``--scene`` the scene named in the run's ``config.yaml``
(``_meta.scene``) is used. Writes ``metrics.json``, ``metrics.md``, normal-map comparison PNGs
and ``config.yaml`` into ``--out``. Protocols: :mod:`voxnero.eval.chamfer`,
:mod:`voxnero.eval.normals`. Image metrics (PSNR/SSIM) need renders, which runs do not write
yet; they are reported as not evaluated.
"""

from __future__ import annotations

import argparse
import textwrap
import time
from pathlib import Path

NAME = "eval"
HELP = "score a mesh against a scene's ground truth (Chamfer, normal error)"
DESCRIPTION = (
    "Score a mesh against a scene's ground truth by the project's protocol: Chamfer distance "
    "(GT test-view depth vs the mesh ray-cast at the same pixels, voxel 0.01, input frame) and "
    "normal error (degrees) at the test views.\n\n"
    "RUN_OR_MESH: a run folder holding mesh.ply (as 'voxnero shape' writes it) or a mesh file, "
    "both in the scene's input frame. --scene: a scene with test_mask/ and gt/test_depth/ "
    "(gt/test_normal/ optional), e.g. a dev scene; default: _meta.scene of the run's "
    "config.yaml.\n\n"
    "Writes metrics.json, metrics.md, normal-map comparison PNGs and config.yaml in --out.\n"
    "Keys (eval section): split, voxel, pred_pixels (unambiguous|mask|all), normal_source "
    "(vertex|face), views ([0, 3, ...]), images (number of comparison PNGs).")
DESCRIPTION = "\n\n".join(textwrap.fill(p, 92) for p in DESCRIPTION.split("\n\n"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from voxnero.cli import add_common

    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    add_common(parser, "run folder holding mesh.ply, or a mesh file (input frame)")
    parser.add_argument("--scene", default=None,
                        help="scene with ground truth (default: the scene in the run's "
                             "config.yaml)")


def find_mesh(target: str | Path) -> Path:
    """The mesh to evaluate: ``target`` itself or ``target/mesh.ply``."""
    from voxnero.errors import DataError

    p = Path(target)
    if p.is_dir():
        if (p / "mesh.ply").is_file():
            return p / "mesh.ply"
        raise DataError("this folder holds no mesh.ply", path=p,
                        fix="pass a finished run folder of 'voxnero shape' or a mesh file")
    if not p.exists():
        raise DataError("no such run folder or mesh file", path=p,
                        fix="pass a run folder holding mesh.ply or a .ply/.obj mesh")
    return p


def find_scene(target: str | Path, scene: str | None) -> Path:
    """``--scene`` if given, else ``_meta.scene`` of the run's ``config.yaml``."""
    import yaml

    from voxnero.errors import ConfigError

    if scene:
        return Path(scene)
    run = Path(target) if Path(target).is_dir() else Path(target).parent
    cfg = run / "config.yaml"
    if cfg.is_file():
        try:
            meta = (yaml.safe_load(cfg.read_text()) or {}).get("_meta", {}) or {}
        except yaml.YAMLError:
            meta = {}
        if meta.get("scene"):
            return Path(meta["scene"])
    raise ConfigError("no scene to evaluate against", fix="pass --scene SCENE_FOLDER (a scene with "
                      "test_mask/ and gt/test_depth/, e.g. a dev scene)")


def evaluate(mesh_path: Path, scene_path: Path, cfg, out: Path) -> dict:
    """Load everything, compute the metrics, write the report; returns the metrics dict."""
    from voxnero.data.detect import load_scene
    from voxnero.errors import DataError
    from voxnero.eval.chamfer import chamfer_at_views
    from voxnero.eval.normals import (
        load_gt_normals,
        normal_error_at_views,
        render_normals,
    )
    from voxnero.eval.report import write_report
    from voxnero.eval.views import MeshCaster, iter_view_rays
    from voxnero.mesh.io import load_mesh

    t0 = time.perf_counter()
    scene = load_scene(scene_path, splits=(cfg.split,), eval_extras=True)
    sp = scene.split(cfg.split)
    if sp.masks is None or sp.depth is None:
        missing = [n for n, v in ((f"{cfg.split}_mask/", sp.masks),
                                  (f"gt/{cfg.split}_depth/", sp.depth)) if v is None]
        raise DataError(f"the scene has no ground truth for evaluation (missing "
                        f"{', '.join(missing)})", path=scene_path,
                        fix="evaluate against a scene with masks and depth of its test views "
                            "(a dev scene or one made by 'voxnero synth')")
    idx = list(range(sp.n)) if cfg.views is None else list(cfg.views)
    bad = [i for i in idx if not 0 <= i < sp.n]
    if bad or not idx:
        from voxnero.errors import ConfigError

        raise ConfigError(f"eval.views={cfg.views} must be indices in [0, {sp.n})")
    cams, depth, masks = sp.cameras[idx], sp.depth[idx], sp.masks[idx]
    names = [sp.names[i] for i in idx]
    mesh = load_mesh(mesh_path, norm=scene.norm)  # unit frame, like the scene's cameras
    t_load = time.perf_counter() - t0

    metrics: dict = {"mesh": str(mesh_path), "scene": str(scene_path), "split": cfg.split,
                     "n_views": len(idx),
                     "mesh_stats": {"vertices": len(mesh.vertices),
                                    "triangles": len(mesh.triangles)}}
    t1 = time.perf_counter()
    rays = list(iter_view_rays(cams))  # shared by both metrics
    ch = chamfer_at_views(mesh, cams, depth, masks, norm=scene.norm, voxel=cfg.voxel,
                          pred_pixels=cfg.pred_pixels, rays=rays)
    ch.pop("n_views", None)
    metrics["chamfer"] = {**ch, "voxel": cfg.voxel, "pred_pixels": cfg.pred_pixels,
                          "frame": "input"}
    if ch["n_pred"] == 0:
        metrics["warning"] = ("no test ray hit the mesh: is it written in the scene's input frame "
                              "(the frame of its cameras)?")
    images = {}
    gt_n = load_gt_normals(scene.root, cfg.split, names)
    if gt_n is not None:
        ne = normal_error_at_views(mesh, cams, gt_n, masks, source=cfg.normal_source, rays=rays)
        metrics["normals"] = {**ne, "source": cfg.normal_source}
        caster = MeshCaster(mesh)
        for k in range(min(cfg.images, len(idx))):
            pred_n, _ = render_normals(caster, cams, k, cfg.normal_source, rays=rays[k][1:3])
            gt_vis = (gt_n[k] * 0.5 + 0.5) * (gt_n[k] != 0).any(-1, keepdims=True)
            pred_vis = (pred_n * 0.5 + 0.5) * (pred_n != 0).any(-1, keepdims=True)
            images[f"normals_{names[k]}"] = (pred_vis, gt_vis)
    else:
        metrics["normals"] = f"not evaluated: no gt/{cfg.split}_normal/ in the scene"
    metrics["images"] = "not evaluated: the run has no renders of the test views"
    metrics["time_s"] = {"load": round(t_load, 3), "metrics": round(time.perf_counter() - t1, 3)}
    write_report(out, metrics, images, title=f"VoxNeRO evaluation of {mesh_path}")
    return metrics


def run(args: argparse.Namespace) -> int:
    from voxnero.config import resolve, save_resolved
    from voxnero.eval.config import EvalConfig

    cfg = resolve(EvalConfig, "eval", args.preset, args.overrides)
    mesh_path = find_mesh(args.target)
    scene_path = find_scene(args.target, args.scene)
    out = Path(args.out)
    save_resolved(out, {"eval": cfg}, meta={"command": "eval", "mesh": str(mesh_path),
                                            "scene": str(scene_path)})
    m = evaluate(mesh_path, scene_path, cfg, out)
    c = m["chamfer"]
    line = (f"chamfer {c['cd']:.5f} (acc {c['acc']:.5f}, comp {c['comp']:.5f}; "
            f"{m['n_views']} views, input frame)")
    if isinstance(m["normals"], dict):
        line += (f"; normal error mean {m['normals']['mean_deg']:.2f} deg, median "
                 f"{m['normals']['median_deg']:.2f} deg")
    print(line)
    if "warning" in m:
        print(f"warning: {m['warning']}")
    print(f"wrote {out / 'metrics.json'} and {out / 'metrics.md'}")
    return 0
