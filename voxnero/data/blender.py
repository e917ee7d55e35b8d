"""Loader of NeRF-synthetic / Blender scenes (``transforms_<split>.json``).

Format: ``transforms_<split>.json`` holds ``frames``, each with ``file_path`` (relative to the
scene folder, with or without extension; ``.png`` is tried first) and ``transform_matrix``
(4x4 camera-to-world, OpenGL/Blender axes: x right, y up, looking down -z). Intrinsics are
``camera_angle_x`` (horizontal FOV, radians; ``camera_angle_y`` optional) and/or the
instant-ngp keys ``fl_x, fl_y, cx, cy, w, h``; a key given in a frame wins over the global one.
Defaults: ``fl_y = fl_x`` (square pixels), ``cx = w / 2``, ``cy = h / 2``, ``w, h`` from the
image. The principal point is taken in the project's pixel frame (pixel centre +0.5), which is
the NeRF-synthetic / Blender convention (centre of the image at ``w / 2``).

Lens distortion given as instant-ngp ``k1, k2, p1, p2`` (OpenCV polynomial) is removed at load
by resampling onto the pinhole camera, exactly as for COLMAP's OPENCV model
(:func:`voxnero.data.colmap.undistort_images`); ``k3``/``k4`` or ``is_fisheye`` are refused.

Poses become OpenCV by ``c2w_gl @ diag(1, -1, -1, 1)``. The world is Blender's, **+Z up**.
RGBA images are composited over black (``white_bg=False``) or white, in linear space, and
their alpha is kept in ``Split.alpha``. With ``eval_extras``, ``<split>_mask/<name>.png`` and
``gt/<split>_depth/<name>.exr`` (dev scenes: z-depth, 0 on background) are loaded too.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from voxnero.cameras.cameras import opengl_to_opencv
from voxnero.data.scene import (
    Scene,
    check_camera,
    check_pose,
    choose_normalisation,
    image_size,
    load_image_stack,
    load_masks,
    make_split,
)
from voxnero.errors import DataError

IMAGE_EXTS = (".png", ".PNG", ".jpg", ".jpeg", ".JPG", ".JPEG")


def is_blender(root: Path) -> bool:
    """True if ``root`` holds at least one ``transforms_*.json``."""
    return any(root.glob("transforms_*.json"))


def _read_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        have = sorted(p.name for p in path.parent.glob("transforms_*.json"))
        raise DataError(f"split file not found (have {have})", path=path,
                        fix="ask for a split that exists, e.g. splits=('train',)")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(f"invalid JSON ({e})", path=path, fix="repair the file") from None
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise DataError("no 'frames' list", path=path,
                        fix="a NeRF-synthetic transforms file needs "
                            "{'camera_angle_x': ..., 'frames': [...]}")
    return data


def _resolve_image(root: Path, file_path: str, json_path: Path, i: int) -> Path:
    rel = Path(str(file_path))
    p = rel if rel.is_absolute() else root / rel
    if p.suffix.lower() in IMAGE_EXTS and p.is_file():
        return p
    tried = [p] if p.suffix.lower() in IMAGE_EXTS else []
    for ext in IMAGE_EXTS:
        q = p.with_name(p.name + ext) if p.suffix.lower() not in IMAGE_EXTS else None
        if q is not None:
            tried.append(q)
            if q.is_file():
                return q
    raise DataError(f"frame {i}: image file not found for file_path {file_path!r} "
                    f"(tried {', '.join(str(t) for t in tried[:3])} ...)", path=json_path,
                    fix="restore the image or correct file_path")


def _focal_from_angle(g: dict[str, Any], key: str, size: int, where: str, path: Path) -> float:
    """Focal length in pixels from the field of view ``g[key]`` (radians) across ``size`` pixels.

    Raises:
        DataError: the angle is not a number in (0, pi) (0 and pi have no pinhole camera).
    """
    try:
        angle = float(g[key])
    except (TypeError, ValueError):
        angle = math.nan
    if not 0.0 < angle < math.pi:
        raise DataError(f"{where}: {key}={g[key]!r} is not a field of view in (0, pi) radians "
                        "(0 to 180 degrees)", path=path,
                        fix=f"give {key} in radians, e.g. 0.6911 for 40 degrees")
    return 0.5 * size / math.tan(0.5 * angle)


def frame_intrinsics(g: dict[str, Any], w: int, h: int, where: str, path: Path) -> np.ndarray:
    """``(3, 3)`` intrinsics of one frame from NeRF-synthetic / instant-ngp keys.

    Args:
        g: the file's global keys updated by the frame's own (``fl_x``, ``fl_y``, ``cx``, ``cy``,
            ``camera_angle_x``, ``camera_angle_y``).
        w: image width in pixels.
        h: image height in pixels.
        where: the frame, for errors (``"frame 3 (./train/r_3)"``).
        path: the transforms file, for errors.

    Returns:
        ``K`` in pixels (pixel centre +0.5): ``fl_x`` or the focal of ``camera_angle_x``,
        ``fl_y`` / ``camera_angle_y`` or ``fx``, principal point ``(cx, cy)`` or the image centre.
        Check it with :func:`voxnero.data.scene.check_camera`.

    Raises:
        DataError: no focal length, non-numeric values, or an angle outside (0, pi).
    """
    try:
        if "fl_x" in g:
            fx = float(g["fl_x"])
        elif "camera_angle_x" in g:
            fx = _focal_from_angle(g, "camera_angle_x", w, where, path)
        else:
            raise DataError(f"{where}: no focal length (camera_angle_x or fl_x)", path=path,
                            fix="add camera_angle_x (radians) or fl_x (pixels)")
        if "fl_y" in g:
            fy = float(g["fl_y"])
        elif "camera_angle_y" in g:
            fy = _focal_from_angle(g, "camera_angle_y", h, where, path)
        else:
            fy = fx
        cx = float(g.get("cx", 0.5 * w))
        cy = float(g.get("cy", 0.5 * h))
    except (TypeError, ValueError) as e:
        raise DataError(f"{where}: bad intrinsics ({e})", path=path,
                        fix="intrinsics must be numbers") from None
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def _parse_split(root: Path, split: str) -> dict[str, Any]:
    """Frames of one split: paths, names, K (N,3,3), OpenCV c2w (N,4,4), width, height."""
    jpath = root / f"transforms_{split}.json"
    data = _read_json(jpath)
    frames = data["frames"]
    if not frames:
        raise DataError(f"split {split!r} is empty (no frames)", path=jpath,
                        fix="add frames or do not ask for this split")
    paths, names, Ks, c2ws, sizes, dists = [], [], [], [], [], []
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
            raise DataError(f"frame {i} lacks 'file_path' or 'transform_matrix'", path=jpath,
                            fix="every frame needs both keys")
        p = _resolve_image(root, fr["file_path"], jpath, i)
        where = f"frame {i} ({fr['file_path']})"
        m = check_pose(fr["transform_matrix"], (4, 4), where, jpath)
        g = {**data, **fr}  # per-frame keys win
        if "w" in g and "h" in g:
            try:
                w, h = int(g["w"]), int(g["h"])
            except (TypeError, ValueError, OverflowError):
                raise DataError(f"{where}: image size w={g['w']!r} h={g['h']!r} is not two "
                                "integers", path=jpath,
                                fix="give w and h in pixels, or drop them to read the size from "
                                    "the image") from None
        else:
            w, h = image_size(p)
        K = frame_intrinsics(g, w, h, where, jpath)
        check_camera(K, opengl_to_opencv(m), w, h, where, jpath)
        try:
            dist = [float(g.get(k, 0.0)) for k in ("k1", "k2", "p1", "p2")]
            extra = [float(g.get(k, 0.0)) for k in ("k3", "k4")]
        except (TypeError, ValueError):
            raise DataError(f"frame {i}: bad distortion coefficients", path=jpath,
                            fix="k1, k2, p1, p2 must be numbers") from None
        if any(extra) or g.get("is_fisheye"):
            raise DataError(f"frame {i}: fisheye or k3/k4 distortion is not supported",
                            path=jpath, fix="undistort the images first "
                                            "(e.g. colmap image_undistorter) and drop the keys")
        paths.append(p)
        names.append(p.stem)
        dists.append(dist)
        Ks.append(K)
        c2ws.append(opengl_to_opencv(m))
        sizes.append((w, h))
    if len(set(sizes)) > 1:
        i = next(k for k, s in enumerate(sizes) if s != sizes[0])
        raise DataError(f"frame {i} is {sizes[i][0]}x{sizes[i][1]} but frame 0 is "
                        f"{sizes[0][0]}x{sizes[0][1]} (mixed image sizes in split {split!r})",
                        path=paths[i], fix="resize all images of a split to one size")
    return {"json": jpath, "paths": paths, "names": names, "K": np.asarray(Ks, np.float64),
            "c2w": np.asarray(c2ws, np.float64), "width": sizes[0][0], "height": sizes[0][1],
            "dist": np.asarray(dists, np.float64)}


def load_blender(root: str | Path, splits=("train",), white_bg: bool = False, radius=None,
                 center=None, bbox=None, eval_extras: bool = False) -> Scene:
    """Load a NeRF-synthetic / Blender scene (see the module docstring).

    The normalisation is computed from the train split's cameras (parsed even if ``train`` is
    not asked for), so every split of a scene shares it; see :mod:`voxnero.data.scene`.
    """
    from voxnero.io.exr import read_exr

    root = Path(root)
    parsed = {s: _parse_split(root, s) for s in splits}
    ref = parsed.get("train")
    if ref is None and (root / "transforms_train.json").is_file():
        ref = _parse_split(root, "train")
    if ref is None:
        ref = next(iter(parsed.values()))
    norm, rec = choose_normalisation(ref["c2w"], ref["K"], ref["width"], ref["height"],
                                     bbox=bbox, radius=radius, center=center)
    out, any_alpha, undistorted = {}, False, False
    for s, p in parsed.items():
        enc = load_image_stack(p["paths"], p["width"], p["height"], s)
        masks = depth = None
        if eval_extras:
            mdir = root / f"{s}_mask"
            if mdir.is_dir():
                masks = load_masks([mdir / f"{n}.png" for n in p["names"]], p["width"],
                                   p["height"], s)
            ddir = root / "gt" / f"{s}_depth"
            if ddir.is_dir():
                depth = np.stack([read_exr(ddir / f"{n}.exr")[..., 0] for n in p["names"]])
                if depth.shape[1:] != (p["height"], p["width"]):
                    raise DataError(f"depth maps are {depth.shape[2]}x{depth.shape[1]}, images "
                                    f"{p['width']}x{p['height']}", path=ddir,
                                    fix="depth maps must match the images")
        sp = make_split(s, enc, p["K"], p["c2w"], norm, p["names"], white_bg, masks, depth)
        if (p["dist"] != 0).any():  # instant-ngp k1, k2, p1, p2: resample like COLMAP's OPENCV
            from voxnero.data.colmap import undistort_images

            dist = torch.from_numpy(p["dist"].astype(np.float32))
            K = sp.cameras.K
            sp.images = undistort_images(sp.images, K, dist)
            for attr in ("alpha", "masks", "depth"):
                v = getattr(sp, attr)
                if v is not None:
                    setattr(sp, attr, undistort_images(v[..., None], K, dist)[..., 0])
            undistorted = True
        any_alpha |= sp.alpha is not None
        out[s] = sp
    return Scene(root=root, format="blender", splits=out, norm=norm,
                 up=np.array([0.0, 0.0, 1.0]),
                 background="alpha" if any_alpha else "unknown",
                 meta={"normalisation": rec, "up_method": "Blender convention (+Z)",
                       "white_bg": bool(white_bg), "undistorted": undistorted,
                       "pose_files": {s: str(p["json"]) for s, p in parsed.items()}})
