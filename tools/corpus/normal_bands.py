"""Split a mesh's normal error at a scene's test views by distance to the GT normal map's edges.

The corpus's mean normal error is far above its median (``standard``: 5.5° against 3.0°, median
over the scenes). This says where the mean comes from: the band of pixels within a pixel or two
of an edge of the GT normal map (a crease of more than ``--edge-deg`` between neighbouring
pixels, or the outline), where a grid's rounding or shift of a corner shows, against the faces
further away. The angles are :func:`voxnero.eval.normals.normal_error_at_views`' (the mesh's
stored vertex normals, the pixels it scores), so the "all" line equals ``voxnero eval``'s.

    python -m tools.corpus.normal_bands RUN/mesh.ply --scene cache/corpus/table_oak

Prints, per band of distance (pixels), its share of the scored pixels, its mean and median
angle and its part of the overall mean (the parts sum to the mean).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

BANDS = ((0.0, 1.5), (1.5, 3.0), (3.0, 5.0), (5.0, np.inf))
"""Distance bands in pixels: the edge pixels and their neighbours, the next two rings, the rest."""


def filtered_normals(caster, cameras, index: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's normal map of one view box-filtered like the corpus's GT normals: the mean of
    the interpolated vertex normals over a ``k × k`` grid of rays in each pixel that hit,
    renormalised (``tools/corpus/render.py`` averages the shading normal over the covered
    samples of a pixel). ``k = 1`` is :func:`voxnero.eval.normals.render_normals`' centre ray.

    Returns:
        ``normals (H, W, 3)`` unit (0 where no ray hit) and ``hit (H, W)`` bool (any ray hit).
    """
    import torch

    from voxnero.cameras.rays import pixel_centers, pixel_rays
    from voxnero.eval.normals import render_normals

    h, w = cameras.height, cameras.width
    centre = pixel_centers(h, w).reshape(-1, 2)
    acc = np.zeros((h, w, 3))
    for i in range(k):
        for j in range(k):
            off = torch.tensor([(j + 0.5) / k - 0.5, (i + 0.5) / k - 0.5])
            o, d = pixel_rays(cameras, torch.full((h * w,), index), centre + off)
            rays = (o.cpu().numpy().astype(np.float64).reshape(h, w, 3),
                    d.cpu().numpy().astype(np.float64).reshape(h, w, 3))
            acc += render_normals(caster, cameras, index, "vertex", rays=rays)[0]  # 0 on a miss
    norm = np.linalg.norm(acc, axis=-1, keepdims=True)
    hit = norm[..., 0] > 1e-12
    return np.where(hit[..., None], acc / np.maximum(norm, 1e-30), 0.0), hit


def band_table(mesh_path: Path, scene_path: Path, edge_deg: float = 20.0,
               k: int = 1) -> list[dict]:
    """Normal error of ``mesh_path`` at the test views of ``scene_path``, by band; with
    ``k > 1`` the mesh's normals are box-filtered over ``k × k`` rays per pixel like the GT's
    (:func:`filtered_normals`).

    Returns:
        one dict per band (``lo``, ``hi`` in pixels, ``share``, ``mean_deg``, ``median_deg``,
        ``part_of_mean_deg``), then one for all scored pixels (``lo`` 0, ``hi`` inf).
    """
    from voxnero.data.detect import load_scene
    from voxnero.eval.normals import (
        angle_deg,
        gt_edge_distance,
        load_gt_normals,
        render_normals,
        scored_pixels,
    )
    from voxnero.eval.views import MeshCaster, full_coverage, iter_view_rays
    from voxnero.mesh.io import load_mesh

    scene = load_scene(scene_path, splits=("test",), eval_extras=True)
    sp = scene.split("test")
    gt = load_gt_normals(scene.root, "test", sp.names)
    if gt is None or sp.masks is None:
        raise SystemExit(f"{scene_path}: no GT normals or masks of the test views "
                         "(gt/test_normal/, test_mask/): a corpus or dev scene is needed")
    mesh = load_mesh(mesh_path, norm=scene.norm)
    caster = MeshCaster(mesh)
    full = full_coverage(sp.masks)
    angles, dists = [], []
    for v, o, d, _ in iter_view_rays(sp.cameras):
        if k == 1:
            pred, hit = render_normals(caster, sp.cameras, v, "vertex", rays=(o, d))
        else:
            pred, hit = filtered_normals(caster, sp.cameras, v, k)
        ok = scored_pixels(gt[v], full[v])
        dist = gt_edge_distance(gt[v], ok, edge_deg)
        m = ok & hit
        angles.append(angle_deg(pred[m], gt[v][m]))
        dists.append(dist[m])
    a, dist = np.concatenate(angles), np.concatenate(dists)
    rows = []
    for lo, hi in (*BANDS, (0.0, np.inf)):
        s = (dist >= lo) & (dist < hi)
        rows.append({"lo": lo, "hi": hi, "share": float(s.mean()),
                     "mean_deg": float(a[s].mean()) if s.any() else float("nan"),
                     "median_deg": float(np.median(a[s])) if s.any() else float("nan"),
                     "part_of_mean_deg": float(a[s].sum() / len(a))})
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mesh", type=Path, help="mesh in the scene's input frame (a run's mesh.ply)")
    ap.add_argument("--scene", type=Path, required=True, help="corpus or dev scene with GT normals")
    ap.add_argument("--edge-deg", type=float, default=20.0,
                    help="angle between neighbouring GT normals that makes an edge (degrees)")
    ap.add_argument("--spp", type=int, default=1,
                    help="k: average the mesh's normals over k x k rays per pixel, as the GT's "
                         "are averaged (1: the centre ray, as voxnero eval)")
    args = ap.parse_args(argv)
    print(f"{args.mesh} at {args.scene} (edges: > {args.edge_deg:g} deg or the outline; "
          f"{args.spp}x{args.spp} rays per pixel)")
    print("band (px)   share   mean   median   part of the mean")
    for r in band_table(args.mesh, args.scene, args.edge_deg, args.spp):
        name = "all" if (r["lo"], r["hi"]) == (0.0, np.inf) else f"{r['lo']:g}-{r['hi']:g}"
        print(f"{name:10s} {r['share']:6.3f} {r['mean_deg']:6.2f}° {r['median_deg']:6.2f}° "
              f"{r['part_of_mean_deg']:8.2f}°")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
