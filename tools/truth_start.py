#!/usr/bin/env python
"""Stage 1 started from the EXACT true surface of a scene with a ground-truth mesh (diagnostic).

``voxnero shape`` as usual (coarse stage, fitted box, decisions), except that the SDF grid is
set, right after the coarse stage (which fits its box), to the true signed distance
(``gt/mesh.ply``, Open3D) at the grid's own corners. Pass ``coarse.sdf_first=1`` so that the
first grid is the last one (otherwise the start is upsampled later and is no longer exact).
Two uses
(docs/STAGE1.md, findings 28–29):

* **drift**: does the free run leave the truth? (``voxnero eval`` the run; compare with the
  exact start's own mesh, which a frozen run writes: add ``optim.lr_sdf=1e-9``);
* **self-rendered photos** (``--self-render DIR``): after training, the model renders its own
  training views (8-bit sRGB PNG, the scene's names, pixel centres or ``--ss K`` × K points per
  pixel averaged in linear RGB, the photos' box filter). Link the scene's other files next to
  ``DIR`` (``DIR`` is the new scene's ``train/``) and train on that scene: photos the stage-1
  model can render exactly, so what a run does there is the optimiser's and the grid's, not
  the appearance model's.

Example::

    python -m tools.truth_start cache/corpus/frame_red --out runs/frozen --preset preview \\
        --self-render cache/self/frame_self/train coarse.race=false coarse.sdf_first=1 \\
        coarse.s_start=400 optim.lr_sdf=1e-9 threads=1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def true_sdf_at_corners(mesh_path: Path, norm, res: int, bounds) -> torch.Tensor:
    """``(1, res, res, res)`` true signed distance (unit frame, negative inside) at the corners
    of a cubic grid with corner positions ``bounds`` ``(2, 3)``; ``norm``: the scene's
    input → unit frame map (:class:`voxnero.data.scene.Normalisation`)."""
    import numpy as np
    import open3d as o3d
    import torch

    from voxnero.fields.grid import grid_points

    gt = o3d.io.read_triangle_mesh(str(mesh_path))
    gt.vertices = o3d.utility.Vector3dVector(norm.to_unit(np.asarray(gt.vertices)))
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(gt))
    pts = grid_points(res, bounds.cpu().float()).reshape(-1, 3).numpy()
    d = rs.compute_signed_distance(o3d.core.Tensor(pts.astype(np.float32))).numpy()
    return torch.from_numpy(d).reshape(1, res, res, res)


def render_views(tr, out: Path, ss: int = 1, chunk: int = 8192) -> None:
    """Write every training view of trainer ``tr`` as rendered by its model to ``out``
    (8-bit sRGB PNG named like the photos); ``ss`` > 1: mean of ``ss × ss`` stratified points
    per pixel (linear radiance, each clipped to [0, 1] as a camera would)."""
    import torch

    from voxnero.cameras.rays import pixel_centers, pixel_rays
    from voxnero.io.images import save_linear_png
    from voxnero.shape import schedules
    from voxnero.shape.renderer import render_rays

    out.mkdir(parents=True, exist_ok=True)
    cams = tr.cams
    corner = pixel_centers(cams.height, cams.width, device=cams.device).reshape(-1, 2) - 0.5
    s = schedules.sharpness(tr.cfg, tr.step)
    nc = schedules.coarse_samples(tr.cfg, tr.step)
    tr.model.env.prepare()
    with torch.no_grad():
        for i, name in enumerate(tr.scene.split("train").names):
            acc = torch.zeros(corner.shape[0], 3, device=cams.device)
            for a in range(ss):
                for b in range(ss):
                    pix = corner + torch.tensor([(a + 0.5) / ss, (b + 0.5) / ss],
                                                device=cams.device)
                    o, d = pixel_rays(cams, torch.full((pix.shape[0],), i), pix)
                    for j in range(0, o.shape[0], chunk):
                        acc[j:j + chunk] += render_rays(tr.model, o[j:j + chunk], d[j:j + chunk],
                                                        s, tr.cfg, train=False,
                                                        coarse=nc)["rgb"].clamp(0, 1)
            img = (acc / (ss * ss)).view(cams.height, cams.width, 3).cpu().numpy()
            save_linear_png(out / f"{name}.png", img)
    tr.model.env.release()
    print(f"[truth_start] rendered {i + 1} training views into {out}", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path, help="scene folder with gt/mesh.ply")
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--preset", default="standard")
    ap.add_argument("--self-render", type=Path, default=None,
                    help="after training, render the training views into this folder")
    ap.add_argument("--ss", type=int, default=1, help="points per pixel side for --self-render")
    ap.add_argument("overrides", nargs="*", help="config overrides key=value")
    a = ap.parse_intermixed_args(argv)
    mesh = a.scene / "gt" / "mesh.ply"
    if not mesh.is_file():
        ap.error(f"{mesh}: no true mesh; this diagnostic needs a scene with ground truth")

    import torch

    from voxnero.cli import main as voxnero_main
    from voxnero.shape import starts
    from voxnero.shape.trainer import ShapeTrainer

    coarse_start = starts.coarse_start

    def exact_start(tr):
        coarse_start(tr)  # the coarse stage fits the grid's box and decides the resolutions
        g = tr.model.sdf
        values = true_sdf_at_corners(mesh, tr.scene.norm, g.grid.shape[-1], g.bounds)
        with torch.no_grad():
            g.grid.copy_(values.to(g.grid))
        print(f"[truth_start] SDF grid {g.grid.shape[-1]}^3 set to the true distance", flush=True)

    starts.coarse_start = exact_start
    if a.self_render is not None:
        run = ShapeTrainer.run

        def run_and_render(tr):
            path = run(tr)
            render_views(tr, a.self_render, a.ss)
            return path

        ShapeTrainer.run = run_and_render
    return voxnero_main(["shape", str(a.scene), "--preset", a.preset, "--out", str(a.out),
                         "--no-progress", *a.overrides])


if __name__ == "__main__":
    sys.exit(main())
