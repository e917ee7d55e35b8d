#!/usr/bin/env python
"""Re-render a built corpus scene's training photos with one effect changed (diagnostic).

Same cameras, shape, materials, map, sampler and spp as ``tools/corpus/build.py``, with the
path depth (``--max-depth 2``: direct light only, no inter-reflection), a Lambertian BSDF
(``--lambert``), a uniform environment of one radiance (``--uniform 1``: no sun, no sky
pattern; the shading left is the object's own occlusion), the environment map clamped at a
quantile of its texels' maximum channel (``--clamp 0.99`` removes a sun) and/or another shape
(``--mesh``: e.g. a frozen stage-1 run's mesh, so that the photos show exactly what the grid
can represent; the cameras stay the scene's, and the test views' masks, depth and normals and
``OUT/gt/mesh.ply`` are re-rendered from that mesh, so ``voxnero eval`` scores against it) set
here. Writes ``OUT/train/`` and ``OUT/train_mask/`` and links every other file of the scene, so
``OUT`` is a scene that trains and evaluates like the original (docs/STAGE1.md, findings 29–31:
on which photos a stage-1 run still drifts names the effect it cannot render). At depth 16 and
no clamp it reproduces the corpus's photos (mean 8-bit difference 0.01 on frame_red).

Example::

    python -m tools.corpus.rerender cache/corpus/frame_red cache/variants/frame_d2 --max-depth 2
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", type=Path, help="a built corpus scene folder")
    ap.add_argument("out", type=Path, help="the new scene folder")
    ap.add_argument("--max-depth", type=int, default=16, help="Mitsuba path depth (corpus: 16)")
    light = ap.add_mutually_exclusive_group()  # a uniform map has nothing left to clamp
    light.add_argument("--clamp", type=float, default=None,
                       help="clamp the map at this quantile of its texels' maximum channel")
    light.add_argument("--uniform", type=float, default=None,
                       help="replace the map by this constant linear radiance (every channel)")
    ap.add_argument("--lambert", action="store_true",
                    help="a two-sided Lambertian BSDF of the same base colour instead of the "
                         "principled one (no specular lobe at all)")
    ap.add_argument("--mesh", type=Path, default=None,
                    help="render this mesh (PLY, the scene's input frame) instead of gt/mesh.ply")
    ap.add_argument("--shared", type=Path, default=None, help="../shared/data (dev scenes' maps)")
    a = ap.parse_args(argv)

    import numpy as np
    from tqdm import tqdm

    from tools.corpus import build, envmaps, render, rigs
    from tools.corpus.scenes import SCENES
    from voxnero.synth.writer import write_gt_maps, write_mesh, write_view

    specs = {s.name: s for s in SCENES}
    if a.scene.name not in specs or not (a.scene / "gt" / "mesh.ply").is_file():
        ap.error(f"{a.scene}: not a built corpus scene (names: {', '.join(specs)})")
    spec = specs[a.scene.name]
    mesh = build.read_mesh(a.scene / "gt" / "mesh.ply")
    c2w, _ = build.scene_cameras(spec, float(np.linalg.norm(mesh.vertices, axis=1).max()))
    env = envmaps.make(spec.env, a.shared or build.DEFAULT_SHARED)
    if a.mesh is not None:  # after the cameras: they are the scene's, not fitted to this mesh
        mesh = build.read_mesh(a.mesh, recompute_normals=True)
        if len(mesh.triangles) == 0:
            ap.error(f"{a.mesh}: no triangles")
    if a.clamp is not None:
        cap = float(np.quantile(env[..., :3].max(-1), a.clamp))
        print(f"map clamped at {cap:.4g} (its maximum {env.max():.4g})")
        env = np.minimum(env, cap)
    if a.uniform is not None:
        if not a.uniform > 0:
            ap.error(f"--uniform {a.uniform}: the radiance must be positive")
        env = np.full_like(env, a.uniform)
    render.set_variant()
    if a.lambert:
        principled = render._bsdf

        def lambert(part: render.Part) -> dict:
            return {"type": "twosided", "material": {
                "type": "diffuse",
                "reflectance": principled(part)["material"]["base_color"]}}

        render._bsdf = lambert
    parts = build._parts(spec, mesh)
    r = render.Renderer(parts, env, build.WIDTH, build.HEIGHT, rigs.FOV_X_DEG)
    if a.max_depth != 16:
        r.scene = r._scene(parts, env, build.WIDTH, build.HEIGHT, rigs.FOV_X_DEG,
                           {"type": "path", "max_depth": a.max_depth})
        r.params[0] = r.mi.traverse(r.scene)
    a.out.mkdir(parents=True, exist_ok=True)
    own = ("train", "train_mask") + (("gt", "test", "test_mask", "test_exr")
                                     if a.mesh is not None else ())
    for f in a.scene.iterdir():
        if f.name not in own and not (a.out / f.name).exists():
            os.symlink(f.resolve(), a.out / f.name)
    if a.mesh is not None:
        (a.out / "gt").mkdir(exist_ok=True)
        for f in (a.scene / "gt").iterdir():
            if (f.name != "mesh.ply" and not f.name.startswith("test_")
                    and not (a.out / "gt" / f.name).exists()):
                os.symlink(f.resolve(), a.out / "gt" / f.name)
        write_mesh(a.out / "gt" / "mesh.ply", mesh.vertices, mesh.triangles, mesh.normals)
        for k in tqdm(range(build.N_TEST), desc=f"{a.out.name} test"):
            geo = r.geometry(c2w["test"][k], 32, seed=1000 + k)
            write_view(a.out, "test", k, r.radiance(c2w["test"][k], 64, seed=1000 + k),
                       geo["coverage"], exr=True)
            write_gt_maps(a.out, k, build.truth_maps(spec, geo, c2w["test"][k]))
    for k in tqdm(range(build.N_TRAIN), desc=a.out.name):
        rgb = r.radiance(c2w["train"][k], 128, seed=k)
        cov = r.geometry(c2w["train"][k], 32, seed=k)["coverage"]
        write_view(a.out, "train", k, rgb, cov, exr=False)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
