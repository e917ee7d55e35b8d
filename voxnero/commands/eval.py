"""``voxnero eval``: score a mesh against a scene's ground truth, or a capture's masks.

``voxnero eval RUN_OR_MESH --scene SCENE --out DIR [key=value ...]``

RUN_OR_MESH is a run folder holding ``mesh.ply`` (written in the scene's input frame by
``voxnero shape``), a mesh file in the input frame, or a stage-2 run folder of ``voxnero
material`` (``model.glb`` + ``envmap.exr``). SCENE is a scene with evaluation data
(``test_mask/`` and ``gt/test_depth/``, optionally ``gt/test_normal/``), e.g. a dev scene or one
made by ``voxnero synth``; without ``--scene`` the scene named in the run's ``config.yaml``
(``_meta.scene``) is used. Writes ``metrics.json``, ``metrics.md``, normal-map comparison PNGs
and ``config.yaml`` into ``--out``. Protocols: :mod:`voxnero.eval.chamfer`,
:mod:`voxnero.eval.normals`. Image metrics (PSNR/SSIM) need renders: for a stage-1 run they are
reported as not evaluated; for a stage-2 run, Chamfer / normal error are computed on the stage-1
mesh it was fitted on (``_meta.mesh`` of its config; ``model.glb``'s mesh if that file is gone)
and the exported asset (``model.glb`` textures + ``envmap.exr``) is rendered at
``eval.material_views`` test views, each the mean of 2 to ``eval.material_passes`` renders of
``eval.material_spp`` samples (until the estimated Monte Carlo noise is
``eval.material_noise_share`` of the error), by
:func:`voxnero.material.evaluate.evaluate_scene`: novel-view PSNR/SSIM, relighting PSNR/SSIM,
albedo PSNR, metallic / roughness MAE, plus ``render_<view>.png`` comparisons.

A real capture without a GT mesh but with object masks (DTU in the NeuS/IDR layout) is scored by
:mod:`voxnero.eval.silhouette`: the mesh is culled by the training views' masks (dilated by
``eval.cull_dilate`` = 2 px; triangles across a mask boundary split to ``eval.cull_edge_px`` = 1 px
first), then silhouette IoU, precision and recall at the held-out views,
and for a stage-2 run the PSNR of its renders inside the held-out masks. Which protocol applies
is :func:`voxnero.eval.protocol.evaluate_target`'s choice.
"""

from __future__ import annotations

import argparse
import textwrap

NAME = "eval"
HELP = "score a run against a scene's ground truth (Chamfer, normals; stage 2: images, BRDF)"
DESCRIPTION = (
    "Score a mesh against a scene's ground truth by the project's protocol: Chamfer distance "
    "(GT test-view depth vs the mesh ray-cast at the same pixels, voxel 0.01, input frame) and "
    "normal error (degrees) at the test views. A scene with gt/mesh.ply is also scored against "
    "the true mesh ray-cast at the pixel centres (chamfer_exact): the stored depth averages each "
    "pixel, so a depth edge inside the object (a cavity's rim) puts points in mid-air, which "
    "flatter a lid.\n\n"
    "RUN_OR_MESH: a run folder holding mesh.ply (as 'voxnero shape' writes it) or a mesh file, "
    "both in the scene's input frame, or a 'voxnero material' folder (model.glb + envmap.exr): "
    "then the stage-1 mesh it was fitted on is scored as above and the exported asset is "
    "rendered at test views for novel-view / relighting PSNR and SSIM, albedo PSNR, metallic "
    "and roughness MAE. --scene: a scene with test_mask/ and gt/test_depth/ "
    "(gt/test_normal/ optional), e.g. a dev scene; default: _meta.scene of the run's "
    "config.yaml.\n\n"
    "Writes metrics.json, metrics.md, normal-map comparison PNGs and config.yaml in --out.\n"
    "Keys (eval section): split, voxel, pred_pixels (unambiguous|mask|all), normal_source "
    "(vertex|face), views ([0, 3, ...]), images (number of comparison PNGs), material_views "
    "(stage 2: test views rendered, default 4, -1 all), material_spp (stage 2: [cos, ggx, env] "
    "samples of one render pass, default [64, 64, 64]), material_passes (stage 2: at most this "
    "many passes per view, default 4; they stop once their noise is material_noise_share, "
    "default 0.1, of the error), material_relight (stage 2: render the relight splits too, "
    "default true; false skips two thirds of the time), material_subpixels (stage 2: points "
    "per pixel of the box "
    "filter, default 16), cull_dilate (captures: mask dilation in px, default 2), "
    "cull_edge_px (captures: triangles across a mask boundary are split to edges of this many "
    "px before the per-vertex culling, "
    "default 1, 0 = off).\n\n"
    "A capture with object masks and no ground truth (NeuS/IDR, e.g. DTU): the mesh is culled by "
    "the training views' masks, then silhouette IoU / precision / recall at the held-out views "
    "(and PSNR inside the masks for a stage-2 run).")
DESCRIPTION = "\n\n".join(textwrap.fill(p, 92) for p in DESCRIPTION.split("\n\n"))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from voxnero.cli import add_common

    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    add_common(parser, "run folder holding mesh.ply, a 'voxnero material' run folder, or a "
               "mesh file (input frame)")
    parser.add_argument("--scene", default=None,
                        help="scene with ground truth (default: the scene in the run's "
                             "config.yaml)")


def run(args: argparse.Namespace) -> int:
    from voxnero.config import resolve, save_resolved
    from voxnero.eval.config import EvalConfig
    from voxnero.eval.protocol import evaluate_target, summary_lines
    from voxnero.safety.folder import RunFolder

    cfg = resolve(EvalConfig, "eval", args.preset, args.overrides)
    with RunFolder(args.out, "eval") as run:
        m = evaluate_target(args.target, args.scene, cfg, run.staging)
        save_resolved(run.staging, {"eval": cfg},
                      meta={"command": "eval", "mesh": m["mesh"], "scene": m["scene"]})
        run.commit()
    for line in summary_lines(m):
        print(line)
    print(f"wrote {run.path / 'metrics.json'} and {run.path / 'metrics.md'}")
    return 0
