"""Write synthetic scenes in the NeRF-synthetic format of the dev scenes.

Layout and conventions are those of ../shared/data/README.md, so every loader and evaluator
works on both::

    transforms_train.json / transforms_test.json   camera_angle_x, w, h, fl_x, fl_y, cx, cy,
                                                   frames[{file_path "./train/r_000",
                                                   transform_matrix (OpenGL/Blender c2w)}]
    train/ test/            8-bit sRGB PNG, round(255 · sRGB(clip(L, 0, 1))), no alpha
    train_mask/ test_mask/  8-bit round(255 · coverage)
    test_exr/               linear radiance, half-float EXR
    gt/mesh.ply             binary PLY with vertex normals (world frame)
    gt/material.json        geometry + material parameters (+ env-map provenance)
    gt/envmap.exr           the env map exactly as rendered
    gt/test_normal/ test_depth/ test_albedo/ test_metallic/ test_roughness/   EXR maps
    scene_info.json         settings, timings, sizes
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from voxnero.cameras.cameras import opencv_to_opengl
from voxnero.io.color import linear_to_srgb
from voxnero.io.exr import write_exr
from voxnero.io.images import write_png


def frame_name(index: int) -> str:
    """File stem of view ``index``: ``r_000``."""
    return f"r_{index:03d}"


def write_json(path: Path, data: dict) -> None:
    """Pretty JSON (indent 1, like the dev scenes)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1))


def write_transforms(root: Path, split: str, c2w_cv: np.ndarray, width: int, height: int,
                     focal: float) -> Path:
    """``transforms_<split>.json`` with OpenGL/Blender camera-to-world matrices.

    Args:
        root: scene folder.
        split: "train" or "test".
        c2w_cv: (N, 4, 4) OpenCV camera-to-world (converted here with ``opencv_to_opengl``).
        width, height: image size in pixels.
        focal: focal length in pixels (square pixels, principal point at the image centre).
    """
    c2w_gl = opencv_to_opengl(np.asarray(c2w_cv, dtype=np.float64))
    doc = {"camera_angle_x": 2.0 * math.atan(0.5 * width / focal), "w": width, "h": height,
           "fl_x": focal, "fl_y": focal, "cx": width / 2.0, "cy": height / 2.0,
           "frames": [{"file_path": f"./{split}/{frame_name(i)}",
                       "transform_matrix": m.tolist()} for i, m in enumerate(c2w_gl)]}
    path = root / f"transforms_{split}.json"
    write_json(path, doc)
    return path


def write_view(root: Path, split: str, index: int, radiance: np.ndarray, coverage: np.ndarray,
               exr: bool) -> None:
    """PNG (sRGB 8-bit) + mask PNG (+ linear EXR in ``<split>_exr/``) of one view.

    Args:
        radiance: (H, W, 3) linear.
        coverage: (H, W) in [0, 1].
        exr: also write the linear radiance as half-float EXR.
    """
    name = frame_name(index)
    write_png(root / split / f"{name}.png", linear_to_srgb(np.clip(radiance, 0.0, 1.0)))
    write_png(root / f"{split}_mask" / f"{name}.png", coverage)
    if exr:
        write_exr(root / f"{split}_exr" / f"{name}.exr", radiance)


def write_gt_maps(root: Path, index: int, maps: dict[str, np.ndarray]) -> None:
    """``gt/test_<map>/r_XXX.exr`` for normal, depth, albedo, metallic, roughness (half float)."""
    name = frame_name(index)
    for key in ("normal", "depth", "albedo", "metallic", "roughness"):
        write_exr(root / "gt" / f"test_{key}" / f"{name}.exr", maps[key])


def write_mesh(path: Path, vertices: np.ndarray, triangles: np.ndarray,
               normals: np.ndarray) -> None:
    """Binary little-endian PLY (double x y z nx ny nz, uchar/int faces), as Open3D writes it.

    Written with numpy so that the command does not pay Open3D's start-up (~1 s CPU).

    Args:
        path: output file.
        vertices: (V, 3) world frame.
        triangles: (F, 3) vertex indices, counter-clockwise seen from outside.
        normals: (V, 3) unit vertex normals.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(vertices)}\n"
              + "".join(f"property double {k}\n" for k in ("x", "y", "z", "nx", "ny", "nz"))
              + f"element face {len(triangles)}\nproperty list uchar int vertex_indices\n"
              "end_header\n")
    vert = np.concatenate([vertices, normals], axis=1).astype("<f8")
    face = np.zeros(len(triangles), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    face["n"], face["idx"] = 3, triangles
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(vert.tobytes())
        f.write(face.tobytes())


def folder_size(root: Path) -> int:
    """Total size in bytes of the files under ``root``."""
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())
