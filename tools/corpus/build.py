#!/usr/bin/env python
"""Build the corpus: render every scene of ``tools/corpus/scenes.py`` with Mitsuba 3.

Writes one folder per scene in the layout of ../shared/data (its README is the reference):
96 train + 16 test views at 256², 8-bit sRGB PNG without alpha with the environment visible,
coverage masks (evaluation only), linear EXR of the test views, two relight splits, and under
``gt/`` the mesh, env maps, material, test normal / depth / albedo / metallic / roughness maps
and visible surface points. Cached and resumable: a finished scene (``scene_info.json``) is
skipped, an interrupted one continues from its last written view.

Needs the tools-only extra: ``pip install -e .[scenes]`` (Mitsuba 3, pybullet for its meshes)
and, for Mitsuba's fast JIT variant, Debian's ``libllvm19``.

Examples::

    python -m tools.corpus.build --out cache/corpus
    python -m tools.corpus.build --out cache/corpus --scenes knot_chrome duck_small --jobs 1
"""

from __future__ import annotations

import argparse
import json
import math
import shutil
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # allow `python tools/corpus/build.py` as well as `-m`
    sys.path.insert(0, str(REPO))

from tools.corpus import envmaps, render, rigs, shapes  # noqa: E402
from tools.corpus.scenes import SceneSpec, by_name  # noqa: E402
from voxnero.mesh.topology import genus  # noqa: E402

WIDTH = HEIGHT = 256
N_TRAIN, N_TEST = 96, 16
DEFAULT_SHARED = REPO.parent / "shared" / "data"


def split_parts(vertices: np.ndarray, triangles: np.ndarray, normals: np.ndarray,
                materials: list, split_z: float | None) -> list[render.Part]:
    """A mesh cut into one :class:`render.Part` per material by face-centroid height: the first
    material at or below ``split_z``, the second above (one part when ``split_z`` is None).
    ``materials`` hold ``base_color``, ``metallic``, ``roughness`` as attributes or keys."""
    def get(m, k):
        return m[k] if isinstance(m, dict) else getattr(m, k)

    def part(v, f, n, m):
        return render.Part(v, f, n, tuple(get(m, "base_color")), get(m, "metallic"),
                           get(m, "roughness"))

    if split_z is None or len(materials) == 1:
        return [part(vertices, triangles, normals, materials[0])]
    below = vertices[triangles].mean(axis=1)[:, 2] <= split_z
    out = []
    for m, sel in zip(materials, (below, ~below), strict=True):
        used, inv = np.unique(triangles[sel], return_inverse=True)
        out.append(part(vertices[used], inv.reshape(-1, 3), normals[used], m))
    return out


def _parts(spec: SceneSpec, mesh: shapes.Mesh) -> list[render.Part]:
    """The mesh cut into one :class:`render.Part` per material (by face-centroid height)."""
    return split_parts(mesh.vertices, mesh.triangles, mesh.normals, list(spec.materials),
                       spec.split_z)


def material_maps(spec: SceneSpec, position: np.ndarray, coverage: np.ndarray
                  ) -> dict[str, np.ndarray]:
    """Per-pixel base colour ``(H, W, 3)``, metallic and roughness ``(H, W)`` (0 on background)
    from the world position of the covered part of each pixel."""
    hit = coverage > 1e-6
    idx = np.zeros(coverage.shape, int)
    if spec.split_z is not None:
        idx = (position[..., 2] > spec.split_z).astype(int)
    base = np.array([m.base_color for m in spec.materials], np.float32)[idx]
    met = np.array([m.metallic for m in spec.materials], np.float32)[idx]
    rough = np.array([m.roughness for m in spec.materials], np.float32)[idx]
    return {"albedo": np.where(hit[..., None], base, 0.0).astype(np.float32),
            "metallic": np.where(hit, met, 0.0).astype(np.float32),
            "roughness": np.where(hit, rough, 0.0).astype(np.float32)}


def z_depth(position: np.ndarray, coverage: np.ndarray, c2w_gl: np.ndarray) -> np.ndarray:
    """``(H, W)`` depth along the camera's viewing axis (-Z of the OpenGL camera); 0 where
    nothing is covered."""
    fwd = -c2w_gl[:3, 2]
    d = (position - c2w_gl[:3, 3]) @ fwd
    return np.where(coverage > 1e-6, d, 0.0).astype(np.float32)


def read_mesh(path: Path, recompute_normals: bool = False) -> shapes.Mesh:
    """A PLY as a :class:`shapes.Mesh` (its stored vertex normals, or the triangles' area-weighted
    ones with ``recompute_normals``)."""
    import open3d as o3d

    m = o3d.io.read_triangle_mesh(str(path))
    if recompute_normals:
        m.compute_vertex_normals()
    return shapes.Mesh(np.asarray(m.vertices), np.asarray(m.triangles),
                       np.asarray(m.vertex_normals))


def scene_cameras(spec: SceneSpec, radius: float) -> tuple[dict[str, np.ndarray], float]:
    """OpenGL camera-to-world matrices ``{"train": (96, 4, 4), "test": (16, 4, 4)}`` of a scene
    whose true mesh reaches ``radius`` from the origin, and the smallest angle (degrees) from a
    test view to a training view."""
    dist = rigs.distance_for_fill(radius, spec.fill)
    d_train = rigs.train_directions(spec.rig, N_TRAIN)
    d_test, min_angle = rigs.test_directions(spec.rig, d_train, N_TEST,
                                             seed=sum(map(ord, spec.name)))
    return ({"train": rigs.look_at_gl(d_train * dist), "test": rigs.look_at_gl(d_test * dist)},
            min_angle)


def truth_maps(spec: SceneSpec, geo: dict[str, np.ndarray], c2w_gl: np.ndarray
               ) -> dict[str, np.ndarray]:
    """The test view's ground-truth maps (normal, z-depth, albedo, metallic, roughness) from a
    :meth:`render.Renderer.geometry` pass ``geo``."""
    return {"normal": geo["normal"],
            "depth": z_depth(geo["position"], geo["coverage"], c2w_gl),
            **material_maps(spec, geo["position"], geo["coverage"])}


def background_check(env: np.ndarray, rgb: np.ndarray, coverage: np.ndarray, c2w_gl: np.ndarray,
                     focal: float) -> float:
    """PSNR (dB, sRGB, clipped) of the rendered background against the env map looked up along
    pixel-centre rays with the README's direction ↔ pixel mapping: confirms the env-map
    orientation and the camera conventions of the written files agree with Mitsuba."""
    from voxnero.io.color import linear_to_srgb

    h, w = coverage.shape
    pred = envmaps.lookup(env, rigs.pixel_directions(c2w_gl, focal, w, h))
    bg = coverage == 0
    a = linear_to_srgb(np.clip(pred[bg], 0, 1))
    b = linear_to_srgb(np.clip(rgb[bg], 0, 1))
    return float(10 * math.log10(1.0 / max(float(np.mean((a - b) ** 2)), 1e-12)))


def write_points(path: Path, points: np.ndarray, normals: np.ndarray) -> None:
    """Binary PLY point cloud with normals (Open3D)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    pc.normals = o3d.utility.Vector3dVector(normals.astype(np.float64))
    path.parent.mkdir(parents=True, exist_ok=True)
    o3d.io.write_point_cloud(str(path), pc)


def build_scene(spec: SceneSpec, out: Path, shared: Path, spp: dict[str, int],
                log=print) -> dict:
    """Render one scene into ``out / spec.name`` (resumable); returns its ``scene_info``."""
    from tqdm import tqdm

    from voxnero.io.exr import write_exr
    from voxnero.synth.writer import (
        folder_size,
        frame_name,
        write_gt_maps,
        write_json,
        write_mesh,
        write_transforms,
        write_view,
    )

    root = out / spec.name
    if (root / "scene_info.json").is_file():
        log(f"{spec.name}: done already ({root})")
        return json.loads((root / "scene_info.json").read_text())
    t0 = time.time()
    timings: dict[str, float] = {}
    # geometry: the ground-truth mesh (cached), its genus
    mesh_path = root / "gt" / "mesh.ply"
    if mesh_path.is_file():
        mesh = read_mesh(mesh_path)
    else:
        mesh = spec.shape()
        write_mesh(mesh_path, mesh.vertices, mesh.triangles, mesh.normals)
    g = genus(mesh.triangles, len(mesh.vertices))
    radius = float(np.linalg.norm(mesh.vertices, axis=1).max())
    timings["mesh"] = time.time() - t0
    # cameras
    dist = rigs.distance_for_fill(radius, spec.fill)
    focal = 0.5 * WIDTH / math.tan(math.radians(rigs.FOV_X_DEG) / 2)
    c2w, min_angle = scene_cameras(spec, radius)
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # OpenGL <-> OpenCV camera axes
    for split in ("train", "test"):
        write_transforms(root, split, c2w[split] @ flip, WIDTH, HEIGHT, focal)
    for env_name in spec.relight:
        write_transforms(root, f"test_relight_{env_name}", c2w["test"] @ flip, WIDTH, HEIGHT,
                         focal)
    # lights
    envs = {name: envmaps.make(name, shared) for name in (spec.env, *spec.relight)}
    write_exr(root / "gt" / "envmap.exr", envs[spec.env])
    for name in spec.relight:
        write_exr(root / "gt" / f"envmap_{name}.exr", envs[name])
    parts = _parts(spec, mesh)

    def todo(split: str, n: int) -> list[int]:
        return [k for k in range(n) if not (root / split / f"{frame_name(k)}.png").is_file()]

    t = time.time()
    r = render.Renderer(parts, envs[spec.env], WIDTH, HEIGHT, rigs.FOV_X_DEG)
    for k in tqdm(todo("train", N_TRAIN), desc=f"{spec.name} train", leave=False):
        rgb = r.radiance(c2w["train"][k], spp["train"], seed=k)
        cov = r.geometry(c2w["train"][k], spp["geometry"], seed=k)["coverage"]
        write_view(root, "train", k, rgb, cov, exr=False)
    timings["train"] = time.time() - t
    t = time.time()
    pts, nrm = [], []
    bg_psnr = float("nan")
    for k in tqdm(range(N_TEST), desc=f"{spec.name} test", leave=False):
        geo = r.geometry(c2w["test"][k], spp["geometry"], seed=1000 + k)
        full = geo["coverage"] >= 1.0 - 1e-6
        pts.append(geo["position"][full])
        nrm.append(geo["normal"][full])
        if (root / "test" / f"{frame_name(k)}.png").is_file() and k:
            continue
        rgb = r.radiance(c2w["test"][k], spp["test"], seed=1000 + k)
        if k == 0:
            bg_psnr = background_check(envs[spec.env], rgb, geo["coverage"], c2w["test"][0],
                                       focal)
        write_view(root, "test", k, rgb, geo["coverage"], exr=True)
        write_gt_maps(root, k, truth_maps(spec, geo, c2w["test"][k]))
    timings["test"] = time.time() - t
    pts_all, nrm_all = np.concatenate(pts), np.concatenate(nrm)
    pick = np.random.default_rng(0).permutation(len(pts_all))[:50000]
    write_points(root / "gt" / "visible_points.ply", pts_all[pick], nrm_all[pick])
    for name in spec.relight:
        t = time.time()
        rr = render.Renderer(parts, envs[name], WIDTH, HEIGHT, rigs.FOV_X_DEG)
        split = f"test_relight_{name}"
        for k in tqdm(todo(split, N_TEST), desc=f"{spec.name} {name}", leave=False):
            rgb = rr.radiance(c2w["test"][k], spp["relight"], seed=2000 + k)
            write_view(root, split, k, rgb, np.zeros(rgb.shape[:2], np.float32), exr=True)
        shutil.rmtree(root / f"{split}_mask", ignore_errors=True)  # the test masks serve
        timings[f"relight_{name}"] = time.time() - t
    material = {
        "renderer": f"Mitsuba {_mitsuba_version()} ({render.set_variant()}), path tracer "
                    "max_depth=16, rr_depth=8, box filter",
        "bsdf": "twosided(principled); GGX alpha = roughness^2; specular 0.5 (dielectric "
                "F0 0.04); Disney diffuse; all other principled parameters 0",
        "materials": [vars(m) | {"base_color": list(m.base_color)} for m in spec.materials],
        "split_z": spec.split_z,
        "material_note": ("one material" if spec.split_z is None else
                          f"faces whose centroid z > {spec.split_z} use the second material"),
        "geometry": {"source": spec.source, "genus": g, "vertices": len(mesh.vertices),
                     "triangles": len(mesh.triangles), "radius": radius},
        "envmaps": {n: {"source": envmaps.SOURCES[n],
                        "file": "gt/envmap.exr" if n == spec.env else f"gt/envmap_{n}.exr",
                        "max_over_median": float(envs[n].max() / np.median(envs[n]))}
                    for n in envs},
    }
    write_json(root / "gt" / "material.json", material)
    info = {"scene": spec.name, "split": "corpus", "resolution": [WIDTH, HEIGHT],
            "camera_angle_x": math.radians(rigs.FOV_X_DEG), "fov_deg": rigs.FOV_X_DEG,
            "radius": dist, "fill": spec.fill, "rig": spec.rig, "rig_note": rigs.RIGS[spec.rig],
            "pixel_size": rigs.pixel_size(dist, WIDTH), "genus": g, "covers": list(spec.covers),
            "n_train": N_TRAIN, "n_test": N_TEST, "min_angle_test_to_train_deg": min_angle,
            "spp": spp, "env": spec.env, "relight": list(spec.relight),
            "verification": {"background_psnr_db": bg_psnr},
            "timings_s": {k: round(v, 1) for k, v in timings.items()}}
    info["size_bytes"] = folder_size(root)
    info["timings_s"]["total"] = round(time.time() - t0, 1)
    write_json(root / "scene_info.json", info)  # last: marks the scene finished
    log(f"{spec.name}: genus {g}, camera distance {dist:.2f}, 1 px = {info['pixel_size']:.4f}, "
        f"background check {bg_psnr:.1f} dB, {info['size_bytes'] / 2**20:.0f} MiB, "
        f"{info['timings_s']['total']:.0f} s")
    return info


def _mitsuba_version() -> str:
    import mitsuba as mi

    return mi.__version__


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True, help="corpus folder (one per scene)")
    ap.add_argument("--scenes", nargs="*", help="scene names (default: all ten)")
    ap.add_argument("--shared", type=Path, default=DEFAULT_SHARED,
                    help="../shared/data (its dev scenes' env maps are used)")
    ap.add_argument("--spp-train", type=int, default=128)
    ap.add_argument("--spp-test", type=int, default=256)
    ap.add_argument("--spp-relight", type=int, default=256)
    ap.add_argument("--spp-geometry", type=int, default=32,
                    help="samples per pixel of the coverage / AOV pass")
    args = ap.parse_args(argv)
    try:
        import mitsuba  # noqa: F401
        import pybullet_data  # noqa: F401
    except ImportError as e:
        print(f"error: {e.name} is missing; install the tools-only extra: "
              "pip install -e '.[scenes]'", file=sys.stderr)
        return 2
    if not (args.shared / "sphere_gold" / "gt" / "envmap.exr").is_file():
        print(f"error: {args.shared} has no sphere_gold/gt/envmap.exr; pass --shared with the "
              "folder of the dev scenes", file=sys.stderr)
        return 2
    variant = render.set_variant()
    spp = {"train": args.spp_train, "test": args.spp_test, "relight": args.spp_relight,
           "geometry": args.spp_geometry}
    t0 = time.time()
    infos = [build_scene(s, args.out, args.shared, spp) for s in by_name(args.scenes)]
    total = sum(i["size_bytes"] for i in infos)
    print(f"corpus: {len(infos)} scenes in {args.out}, {total / 2**20:.0f} MiB, "
          f"{time.time() - t0:.0f} s this call (Mitsuba {variant})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
