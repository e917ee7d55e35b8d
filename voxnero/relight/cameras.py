"""Cameras to relight from, all returned in the scene's INPUT frame (OpenCV ``c2w``).

* :func:`scene_cameras`: a split of a dataset (``test``, ``test_relight_<env>`` ...) through
  ``voxnero.data.detect.load_scene`` (any format), mapped back from its unit frame.
* :func:`transforms_cameras`: a NeRF-synthetic ``transforms*.json`` on its own (images need not
  exist): ``transform_matrix`` is OpenGL/Blender camera-to-world, converted once with
  ``voxnero.cameras.cameras.opengl_to_opencv``; focal length from ``fl_x``/``fl_y`` or
  ``camera_angle_x``; size from ``w``/``h`` (default 800); intrinsics parsed and every camera
  checked as the Blender loader does (``frame_intrinsics``, ``check_camera``).
* :func:`orbit_cameras`: a turntable of N frames around an up axis at one elevation, looking at
  a centre, without roll.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from voxnero.cameras.cameras import Cameras, look_at_opencv, opengl_to_opencv
from voxnero.data.blender import frame_intrinsics
from voxnero.data.scene import check_camera, check_pose
from voxnero.errors import DataError


def scene_cameras(scene: str | Path, split: str = "test"
                  ) -> tuple[Cameras, list[str], np.ndarray]:
    """Cameras of one split of a scene, input frame, and the split's photos.

    Args:
        scene: scene folder (Blender / NeRO / COLMAP).
        split: split name.

    Returns:
        (cameras with c2w in the input frame, image names, (N, H, W, 3) LINEAR images).
    """
    from voxnero.data.detect import available_splits, load_scene

    have = available_splits(scene)
    if split not in have:
        raise DataError(f"split {split!r} not in this scene (has {have})", path=scene,
                        fix="choose --split among the scene's splits")
    sc = load_scene(scene, splits=(split,))
    sp = sc.split(split)
    c2w = sp.cameras.c2w.clone()
    c2w[:, :3, 3] = sc.norm.to_input(c2w[:, :3, 3].double()).float()
    return (Cameras(sp.cameras.K.clone(), c2w, sp.cameras.width, sp.cameras.height),
            list(sp.names), sp.images.numpy())


def transforms_cameras(path: str | Path) -> tuple[Cameras, list[str]]:
    """Cameras of a ``transforms.json`` (NeRF-synthetic / instant-ngp keys), input frame.

    Args:
        path: the JSON file.

    Returns:
        (cameras, frame names from ``file_path`` stems or ``r_<k>``).
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        frames = data["frames"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as e:
        raise DataError(f"cannot read camera frames ({e})", path=path,
                        fix="give a transforms.json with a 'frames' list") from None
    if not frames:
        raise DataError("no frames", path=path, fix="add frames with transform_matrix")
    Ks, c2ws, names, sizes = [], [], [], set()
    for i, fr in enumerate(frames):
        if not isinstance(fr, dict):
            raise DataError(f"frame {i} is not a mapping", path=path,
                            fix="every frame needs transform_matrix (and file_path)")
        g = {**data, **fr}
        where = f"frame {i} ({fr.get('file_path', f'r_{i}')})"
        try:
            w, h = int(g.get("w", 800)), int(g.get("h", g.get("w", 800)))
        except (TypeError, ValueError, OverflowError):
            raise DataError(f"{where}: image size w={g.get('w')!r} h={g.get('h')!r} is not two "
                            "integers", path=path, fix="give w and h in pixels") from None
        K = frame_intrinsics(g, w, h, where, path)
        m = check_pose(fr.get("transform_matrix"), (4, 4), where, path)
        c2w = opengl_to_opencv(m)
        check_camera(K, c2w, w, h, where, path)
        Ks.append(K)
        c2ws.append(c2w)
        names.append(Path(str(fr.get("file_path", f"r_{i}"))).stem or f"r_{i}")
        sizes.add((w, h))
    if len(sizes) > 1:
        raise DataError(f"frames of different sizes {sorted(sizes)}", path=path,
                        fix="use one image size")
    w, h = sizes.pop()
    return Cameras(np.asarray(Ks), np.asarray(c2ws), w, h), names


def orbit_cameras(center: np.ndarray, radius: float, up: np.ndarray, frames: int = 36,
                  elevation_deg: float = 20.0, distance: float = 0.0, fov_deg: float = 40.0,
                  size: int = 256, start_deg: float = 0.0) -> tuple[Cameras, list[str]]:
    """A turntable around ``up`` through ``center``.

    Args:
        center: (3,) point looked at (input frame).
        radius: radius of the object's bounding sphere (sets the automatic distance).
        up: (3,) up axis.
        frames: number of views, evenly spaced over 360°.
        elevation_deg: angle above the plane perpendicular to ``up``.
        distance: camera distance from ``center``; 0 = the bounding sphere fills 80 % of the
            image height (``radius / sin(0.8 · fov / 2)``).
        fov_deg: vertical = horizontal field of view (square images).
        size: image width = height in pixels.
        start_deg: azimuth of the first frame.

    Returns:
        (cameras, names ``orbit_000`` ...).
    """
    if frames < 1 or size < 1:
        raise DataError(f"orbit needs frames >= 1 and size >= 1 (got {frames}, {size})",
                        fix="set orbit.frames / orbit.size")
    up = np.asarray(up, float) / np.linalg.norm(up)
    a = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = a - up * (a @ up)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    half = math.radians(fov_deg) / 2
    dist = distance if distance > 0 else radius / math.sin(0.8 * half)
    f = 0.5 * size / math.tan(half)
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1]])
    el = math.radians(elevation_deg)
    eyes = []
    for k in range(frames):
        az = math.radians(start_deg) + 2 * math.pi * k / frames
        d = math.cos(el) * (math.cos(az) * e1 + math.sin(az) * e2) + math.sin(el) * up
        eyes.append(np.asarray(center, float) + dist * d)
    c2ws = look_at_opencv(np.asarray(eyes), np.asarray(center, float), tuple(up))
    return (Cameras(np.repeat(K[None], frames, 0), c2ws, size, size),
            [f"orbit_{k:03d}" for k in range(frames)])


def scaled(cameras: Cameras, scale: float) -> Cameras:
    """Same views at ``scale`` × the resolution (K scaled about the image origin).

    Args:
        cameras: the cameras.
        scale: factor (> 0); the size becomes ``round(scale · W) × round(scale · H)``.
    """
    if scale == 1.0:
        return cameras
    w, h = max(1, round(cameras.width * scale)), max(1, round(cameras.height * scale))
    K = cameras.K.clone()
    K[:, 0] *= w / cameras.width
    K[:, 1] *= h / cameras.height
    return Cameras(K, cameras.c2w.clone(), w, h)
