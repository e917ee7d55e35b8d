"""Scoring a reconstruction of a real capture without a ground-truth mesh (e.g. DTU in the
NeuS/IDR layout): masks of the training views cull the mesh, masks of the held-out views score
its silhouettes, and, for a stage-2 run, held-out photos score its renders inside the masks.
The protocol is :mod:`voxnero.eval.silhouette`'s."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np


def evaluate_capture(mesh_path: Path, scene_path: Path, cfg, out: Path,
                     stage2_run: Path | None = None) -> dict:
    """Cull by the training masks, score silhouettes (and renders) at the held-out views.

    Args:
        mesh_path: mesh in the scene's input frame (``.ply``/``.obj``, or a ``model.glb``).
        scene_path: capture with masks for its ``train`` and ``cfg.split`` splits.
        cfg: :class:`voxnero.eval.config.EvalConfig` (``split``, ``cull_dilate``, ``images``,
            ``material_spp``, ``material_views``).
        out: report folder (``metrics.json``/``.md``, ``mesh_culled.ply``, silhouette PNGs).
        stage2_run: a ``voxnero material`` folder: its asset is rendered at the held-out views
            and scored by PSNR inside the masks (sRGB, [0, 1]).

    Returns:
        The metrics dict.
    """
    from voxnero.data.detect import load_scene
    from voxnero.errors import DataError
    from voxnero.eval.report import write_report
    from voxnero.eval.silhouette import (
        cull_refined,
        silhouette_scores,
        silhouettes,
    )
    from voxnero.mesh.io import load_mesh

    t0 = time.perf_counter()
    scene = load_scene(scene_path, splits=("train", cfg.split), eval_extras=True)
    tr, te = scene.split("train"), scene.split(cfg.split)
    if tr.masks is None or te.masks is None:
        raise DataError(f"the scene has no ground truth for evaluation (no gt/{cfg.split}_depth/) "
                        f"and no object masks (train_mask/ and {cfg.split}_mask/, or mask/ of a "
                        "NeuS/IDR capture)", path=scene_path,
                        fix="evaluate against a scene with ground truth (a dev scene or one made "
                            "by 'voxnero synth') or a capture with masks")
    if mesh_path.suffix.lower() == ".glb":
        from voxnero.asset.load import load_asset

        mesh = load_asset(mesh_path).legacy_mesh(scene.norm)
    else:
        mesh = load_mesh(mesh_path, norm=scene.norm)  # unit frame, like the cameras
    t_load = time.perf_counter() - t0
    t1 = time.perf_counter()
    culled, rec = cull_refined(mesh, tr.cameras, tr.masks, cfg.cull_dilate, cfg.cull_edge_px)
    pred = silhouettes(culled, te.cameras)
    sc = silhouette_scores(pred, te.masks)
    metrics: dict = {
        "mesh": str(mesh_path), "scene": str(scene_path), "split": cfg.split,
        "protocol": "capture without a GT mesh: cull by the training masks, silhouettes at the "
                    "held-out views (voxnero.eval.silhouette)",
        "n_views": te.n, "n_train_views": tr.n,
        "mesh_stats": {"vertices": len(mesh.vertices), "triangles": len(mesh.triangles),
                       "kept_vertices": rec.pop("kept_vertices"),
                       "culled_triangles": len(culled.triangles)},
        "cull": rec, "silhouette": sc}
    if len(culled.triangles) == 0:
        metrics["warning"] = ("nothing of the mesh lies inside the training masks: is it in the "
                              "capture's world frame?")
    import open3d as o3d

    out.mkdir(parents=True, exist_ok=True)
    if len(culled.triangles):
        o3d.io.write_triangle_mesh(str(out / "mesh_culled.ply"), _to_input(culled, scene.norm))
    images = {}
    gt = te.masks.numpy() >= 0.5
    for k in range(min(cfg.images, te.n)):
        images[f"silhouette_{te.names[k]}"] = (np.repeat(pred[k, ..., None], 3, -1) * 1.0,
                                               np.repeat(gt[k, ..., None], 3, -1) * 1.0)
    times = {"load": round(t_load, 3), "metrics": round(time.perf_counter() - t1, 3)}
    for k in range(min(cfg.images, te.n)):
        write_view_strip(out / f"views_{te.names[k]}.png", te, k, mesh, culled)
    if stage2_run is not None:
        t2 = time.perf_counter()
        psnr_rec, renders = masked_psnr_stage2(stage2_run, scene.norm, te, cfg)
        metrics["images"] = psnr_rec
        images.update(renders)
        times["stage2"] = round(time.perf_counter() - t2, 3)
    else:
        metrics["images"] = ("not evaluated: a stage-1 run has no renders of the held-out views "
                             "(evaluate the 'voxnero material' folder for PSNR in the masks)")
    metrics["time_s"] = times
    write_report(out, metrics, images, title=f"VoxNeRO evaluation of {mesh_path} (capture)")
    return metrics


def write_view_strip(path: Path, split, k: int, mesh, culled) -> None:
    """``photo | normals of the mesh | normals of the culled mesh`` at view ``k`` (PNG; normals
    in the world frame as ``0.5 n + 0.5``, grey where no surface)."""
    from voxnero.eval.normals import render_normals
    from voxnero.eval.views import MeshCaster
    from voxnero.io.color import linear_to_srgb
    from voxnero.io.images import write_png

    panels = [linear_to_srgb(split.images[k].clamp(0, 1)).numpy()]
    for m in (mesh, culled):
        img = np.full((split.height, split.width, 3), 0.5)
        if len(m.triangles):
            m.compute_vertex_normals()
            n, hit = render_normals(MeshCaster(m), split.cameras, k)
            img[hit] = n[hit] * 0.5 + 0.5
        panels.append(img)
    gap = np.ones((split.height, 4, 3))
    strip = np.concatenate([panels[0], gap, panels[1], gap, panels[2]], 1)
    write_png(path, np.clip(strip, 0, 1))


def _to_input(mesh, norm):
    import open3d as o3d

    out = o3d.geometry.TriangleMesh(mesh)
    out.vertices = o3d.utility.Vector3dVector(norm.to_input(np.asarray(mesh.vertices)))
    return out


def masked_psnr_stage2(run: Path, norm, split, cfg) -> tuple[dict, dict]:
    """Render a stage-2 asset at held-out views; PSNR (sRGB) inside each view's mask.

    Returns:
        ``({"psnr_masked": pooled dB, "per_view": [...], "views": [...]}, {name: (pred, gt)})``.
    """
    import torch

    from voxnero.asset.load import load_asset
    from voxnero.eval.images import psnr
    from voxnero.io.color import linear_to_srgb
    from voxnero.io.exr import read_envmap
    from voxnero.material.evaluate import render_view
    from voxnero.material.render import Strategies
    from voxnero.material.surface import Geometry

    asset = load_asset(run / "model.glb")
    geom = Geometry.from_legacy(asset.legacy_mesh(norm))
    env = torch.from_numpy(read_envmap(run / "envmap.exr")).float()
    spp = Strategies(*(int(x) for x in cfg.material_spp))
    n = split.n if cfg.material_views < 0 else min(cfg.material_views, split.n)
    views = sorted({int(round(v)) for v in np.linspace(0, split.n - 1, n)})
    gen = torch.Generator().manual_seed(1234)
    preds, gts, ms, images = [], [], [], {}
    for i in views:
        r = render_view(geom, asset.field, env, split.cameras, i, spp, True, True,
                        generator=gen, subpixels=cfg.material_subpixels, diffuse=asset.diffuse)
        p = linear_to_srgb(r["rgb"].clamp(0, 1))
        g = linear_to_srgb(split.images[i].clamp(0, 1))
        preds.append(p)
        gts.append(g)
        ms.append(split.masks[i] >= 0.5)
        if len(images) < cfg.images:
            images[f"render_{split.names[i]}"] = (p, g)
    P, G, M = torch.stack(preds), torch.stack(gts), torch.stack(ms)
    per = [psnr(P[k], G[k], M[k]) for k in range(len(views))]
    return ({"psnr_masked": psnr(P, G, M), "per_view": per, "views": views,
             "space": "sRGB in [0, 1], pixels with mask >= 0.5"}, images)
