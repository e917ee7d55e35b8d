"""Scoring against a scene with ground truth (a dev scene or ``voxnero synth``): Chamfer (NeRO
protocol, :mod:`voxnero.eval.chamfer`) and normal error (:mod:`voxnero.eval.normals`) at the test
views; for a stage-2 run also the exported asset's images and materials
(:func:`voxnero.material.evaluate.evaluate_scene`)."""

from __future__ import annotations

import time
from pathlib import Path


def stage2_metrics(run: Path, scene_path: Path, cfg, split) -> tuple[dict, dict]:
    """Image and material metrics of a stage-2 run, by :func:`voxnero.material.evaluate`.

    The exported asset is what is scored: ``model.glb`` (mesh + baked textures, read by
    :func:`voxnero.asset.load.load_asset`) and ``envmap.exr``, rendered at ``cfg.material_views``
    test views, each the mean of up to ``cfg.material_passes`` renders of ``cfg.material_spp``
    samples (:func:`voxnero.material.evaluate.render_converged`); indirect light / visibility
    casts as the run decided (``decisions`` in ``materials.json``).

    Args:
        run: the ``voxnero material`` output folder.
        scene_path: scene with a ``test`` split (and ``gt/test_*`` material maps, relight splits
            if any).
        cfg: :class:`voxnero.eval.config.EvalConfig`.
        split: the loaded ``test`` split (cameras in the unit frame, linear images), for the
            comparison PNGs.

    Returns:
        ``(metrics, images)``: metrics as :func:`voxnero.material.evaluate.evaluate_scene` returns
        them (plus ``asset``, ``indirect``, ``visibility``), and ``{name: (pred, gt)}`` sRGB
        renders of the first ``cfg.images`` evaluated views.
    """
    import json

    import torch

    from voxnero.asset.load import load_asset
    from voxnero.data.detect import load_scene
    from voxnero.io.color import linear_to_srgb
    from voxnero.io.exr import read_envmap
    from voxnero.material.evaluate import evaluate_scene, render_view
    from voxnero.material.render import Strategies
    from voxnero.material.surface import Geometry

    asset = load_asset(run / "model.glb")
    norm = load_scene(scene_path, splits=("test",)).norm  # the frame evaluate_scene uses
    geom = Geometry.from_legacy(asset.legacy_mesh(norm))
    env = torch.from_numpy(read_envmap(run / "envmap.exr")).float()
    dec = {}
    if (run / "materials.json").is_file():
        dec = json.loads((run / "materials.json").read_text()).get("decisions", {}) or {}
    # the light model stage 2 trained with ("traced", "splitsum", "off"); runs written before
    # it was recorded hold only the bool, which evaluate_scene decides per view
    indirect = dec.get("indirect_model") or bool(dec.get("indirect", True))
    visibility = bool(dec.get("visibility_casts", True))
    spp = Strategies(*(int(x) for x in cfg.material_spp))
    res = evaluate_scene(scene_path, geom, asset.field, env, spp, indirect, visibility,
                         views=cfg.material_views, out_dir=None, log=lambda _: None,
                         subpixels=cfg.material_subpixels, passes=cfg.material_passes,
                         noise_share=cfg.material_noise_share, diffuse=asset.diffuse,
                         relight=cfg.material_relight)
    if not res:
        return {"novel_view": "not evaluated: the scene has no test split"}, {}
    res.update(asset=str(run / "model.glb"), indirect=indirect, visibility=visibility)
    images = {}
    gen = torch.Generator().manual_seed(1234)
    if split is not None and split.images is not None:
        for i in res["views"][:cfg.images]:
            r = render_view(geom, asset.field, env, split.cameras, i, spp, indirect, visibility,
                            generator=gen, subpixels=cfg.material_subpixels,
                            diffuse=asset.diffuse)
            images[f"render_{split.names[i]}"] = (linear_to_srgb(r["rgb"].clamp(0, 1)),
                                                  linear_to_srgb(split.images[i].clamp(0, 1)))
    return res, images


def exact_chamfer(mesh, truth, cams, depth, masks, norm, cfg, rays) -> dict:
    """The Chamfer against the true mesh's depth at the pixel centres, and the truth's own score
    against the stored depth (:mod:`voxnero.eval.chamfer`'s docstring: the stored depth is a
    pixel average, with mid-air points at depth edges inside the object).

    Args:
        mesh: predicted legacy mesh, unit frame.
        truth: the scene's ``gt/mesh.ply``, unit frame.
        cams: ``V`` test cameras (unit frame); depth, masks: ``(V, H, W)`` stored GT depth (unit
            frame) and coverage; norm: the scene's normalisation; cfg: the eval config; rays:
            ``list(iter_view_rays(cams))``.

    Returns:
        dict ``cd``, ``acc``, ``comp``, ``n_pred``, ``n_gt`` (input frame, as ``chamfer``), and
        ``truth_cd``: the true mesh scored by the protocol against the stored depth (its floor).
    """
    from voxnero.eval.chamfer import chamfer_at_views, mesh_depth_at_views
    from voxnero.eval.views import MeshCaster

    centre = mesh_depth_at_views(MeshCaster(truth), cams, rays)
    kw = dict(norm=norm, voxel=cfg.voxel, pred_pixels=cfg.pred_pixels, rays=rays)
    out = chamfer_at_views(mesh, cams, centre, masks, **kw)
    out.pop("n_views", None)
    out["truth_cd"] = chamfer_at_views(truth, cams, depth, masks, **kw)["cd"]
    out["gt"] = "gt/mesh.ply ray-cast at the pixel centres of the full-coverage pixels"
    return out


def evaluate(mesh_path: Path, scene_path: Path, cfg, out: Path,
             stage2_run: Path | None = None) -> dict:
    """Load everything, compute the metrics, write the report; returns the metrics dict.

    Args:
        mesh_path: mesh in the scene's input frame (``.ply``/``.obj``, or a ``model.glb``).
        scene_path: scene with ground truth.
        cfg: :class:`voxnero.eval.config.EvalConfig`.
        out: report folder.
        stage2_run: a ``voxnero material`` output folder: its image / material metrics are
            added (:func:`stage2_metrics`).
    """
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
    if mesh_path.suffix.lower() == ".glb":
        from voxnero.asset.load import load_asset

        mesh = load_asset(mesh_path).legacy_mesh(scene.norm)
    else:
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
    truth_path = scene.root / "gt" / "mesh.ply"
    if truth_path.is_file():
        metrics["chamfer_exact"] = exact_chamfer(mesh, load_mesh(truth_path, norm=scene.norm),
                                                 cams, depth, masks, scene.norm, cfg, rays)
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
    t_mesh = time.perf_counter() - t1
    times = {"load": round(t_load, 3), "metrics": round(t_mesh, 3)}
    if stage2_run is None:
        metrics["images"] = "not evaluated: the run has no renders of the test views"
    else:
        t2 = time.perf_counter()
        test = sp if cfg.split == "test" else None
        s2, s2_images = stage2_metrics(stage2_run, scene_path, cfg, test)
        metrics["run"] = str(stage2_run)
        metrics.update(s2)
        images.update(s2_images)
        times["stage2"] = round(time.perf_counter() - t2, 3)
    metrics["time_s"] = times
    write_report(out, metrics, images, title=f"VoxNeRO evaluation of {mesh_path}")
    return metrics
