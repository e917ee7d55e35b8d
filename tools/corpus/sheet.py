#!/usr/bin/env python
"""Contact sheet of the corpus: a test photo of each scene next to the true mesh and today's
reconstructions, all seen from the same test camera.

Meshes are drawn by Open3D ray casting with their normals as colour (``0.5 + 0.5 n``, world
frame), so shape and topology can be compared at a glance; photos are the 8-bit sRGB PNGs.

Example::

    python -m tools.corpus.sheet --corpus cache/corpus --bench cache/bench \\
        --out docs/corpus_sheet.png
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from tools.corpus.bench import run_dirs  # noqa: E402
from tools.corpus.rigs import pixel_directions  # noqa: E402


def normal_image(mesh_path: Path, c2w_gl: np.ndarray, focal: float, width: int, height: int
                 ) -> np.ndarray:
    """``(H, W, 3)`` in [0, 1]: the mesh's world normals seen from an OpenGL camera (white
    background)."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(mesh_path))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    d = pixel_directions(c2w_gl, focal, width, height)
    rays = np.concatenate([np.broadcast_to(c2w_gl[:3, 3], d.shape), d], axis=-1)
    hit = scene.cast_rays(o3d.core.Tensor(rays.astype(np.float32)))
    n = hit["primitive_normals"].numpy()
    n = n * np.where((n * d).sum(-1, keepdims=True) > 0, -1.0, 1.0)  # face the camera
    ok = np.isfinite(hit["t_hit"].numpy())[..., None]
    return np.where(ok, 0.5 + 0.5 * n, 1.0)


def main(argv: list[str] | None = None) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from PIL import Image

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--corpus", type=Path, required=True)
    ap.add_argument("--bench", type=Path, default=None, help="folder of tools.corpus.bench")
    ap.add_argument("--presets", nargs="*", default=["preview", "standard"])
    ap.add_argument("--view", type=int, default=0, help="test view index")
    ap.add_argument("--out", type=Path, required=True, help="PNG to write")
    args = ap.parse_args(argv)
    scenes = sorted(p.parent for p in args.corpus.glob("*/scene_info.json"))
    # column titles name the preset only: overrides (e.g. the carved start alone) are the caption's
    cols = ["photo (test view)", "true mesh"] + [f"`{p.split()[0]}` mesh" for p in args.presets]
    fig, axes = plt.subplots(len(scenes), len(cols), figsize=(2.0 * len(cols),
                                                               2.0 * len(scenes)), squeeze=False)
    for r, root in enumerate(scenes):
        doc = json.loads((root / "transforms_test.json").read_text())
        fr = doc["frames"][args.view]
        c2w = np.array(fr["transform_matrix"], dtype=float)
        w, h, f = int(doc["w"]), int(doc["h"]), float(doc["fl_x"])
        photo = np.asarray(Image.open(root / f"{fr['file_path']}.png")) / 255.0
        imgs = [photo, normal_image(root / "gt" / "mesh.ply", c2w, f, w, h)]
        for preset in args.presets:
            mesh = (run_dirs(args.bench, root.name, preset)[0] / "mesh.ply"
                    if args.bench else None)
            imgs.append(normal_image(mesh, c2w, f, w, h) if mesh and mesh.is_file()
                        else np.ones((h, w, 3)))
        for c, img in enumerate(imgs):
            ax = axes[r, c]
            ax.imshow(np.clip(img, 0, 1))
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(cols[c], fontsize=9)
            if c == 0:
                ax.set_ylabel(root.name, fontsize=8)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=80)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
