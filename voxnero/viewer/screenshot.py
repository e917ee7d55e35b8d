"""Headless screenshots with Open3D's ``OffscreenRenderer`` (Filament).

On a machine without a display Open3D falls back to headless rendering on software Vulkan
(Mesa llvmpipe; packages libvulkan1 + mesa-vulkan-drivers, see tools/install_sysdeps.sh). No
environment variable is needed with open3d 0.20 (``EGL_PLATFORM=surfaceless`` and
``OPEN3D_CPU_RENDERING=true`` change nothing there); the first frame compiles Filament's shaders
(~10-30 s on a busy CPU), later frames of the same renderer take a few seconds, so several
channels are rendered with one renderer.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from voxnero.viewer.geometry import Drawable


def default_view(center: np.ndarray, radius: float, up: np.ndarray, fov_deg: float = 40.0,
                 azimuth_deg: float = 0.0, elevation_deg: float = 20.0,
                 fill: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """Eye point looking at ``center`` so that a sphere of ``radius`` fills ``fill`` of the view.

    Returns:
        eye (3,), up (3,).
    """
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    a = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = a - up * (a @ up)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    d = math.cos(el) * (math.cos(az) * -e2 + math.sin(az) * e1) + math.sin(el) * up
    dist = radius / math.sin(fill * math.radians(fov_deg) / 2)
    return np.asarray(center, dtype=np.float64) + dist * d, up


def render_screenshots(drawables_per_shot: list[list[Drawable]], paths: list[str | Path],
                       center: np.ndarray, eye: np.ndarray, up: np.ndarray,
                       width: int = 640, height: int = 480, fov_deg: float = 40.0,
                       background=(1.0, 1.0, 1.0, 1.0)) -> list[np.ndarray]:
    """Render several shots with one offscreen renderer and write them as PNGs.

    Args:
        drawables_per_shot: the geometries of each shot (replaced between shots).
        paths: one PNG path per shot.
        center, eye, up: (3,) look-at of the camera (input frame).
        width, height: image size in pixels.
        fov_deg: vertical field of view.
        background: RGBA background colour.

    Returns:
        The (height, width, 3) uint8 images.
    """
    import open3d.visualization.rendering as rendering
    from PIL import Image

    r = rendering.OffscreenRenderer(int(width), int(height))
    r.scene.set_background(list(background))
    r.scene.scene.set_sun_light([-0.3, -0.4, -1.0], [1.0, 1.0, 1.0], 60000)
    r.scene.scene.enable_sun_light(True)
    r.scene.set_lighting(rendering.Open3DScene.LightingProfile.MED_SHADOWS,
                         np.array([-0.3, -0.4, -1.0], dtype=np.float32))
    out = []
    for drawables, path in zip(drawables_per_shot, paths, strict=True):
        r.scene.clear_geometry()
        for d in drawables:
            r.scene.add_geometry(d.name, d.geometry, d.material)
        r.setup_camera(float(fov_deg), np.asarray(center, np.float32),
                       np.asarray(eye, np.float32), np.asarray(up, np.float32))
        img = np.asarray(r.render_to_image())[..., :3].copy()
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(img).save(path)
        out.append(img)
    return out
