"""Camera placement for synthetic scenes, like the dev scenes (see ../shared/data/README.md).

Cameras sit at ``distance`` from the origin, look at the origin with world up +Z (no roll),
field of view ``fov_deg`` (square images). Directions come from a Fibonacci lattice over an
elevation band, area-uniform in z = sin(elevation), top first:
``z_k = z_hi − (k + offset)/n · (z_hi − z_lo)``, ``phi_k = phase + k · golden_angle``.
Train uses offset 0.5 and phase 0 (the dev scenes' train lattice up to its azimuth phase); test
uses a second lattice whose (offset, phase) a seeded search picks to maximise the minimum angle
to any train view.

Poses are built in the internal OpenCV convention (x right, y down, z forward) and returned as
:class:`voxnero.cameras.cameras.Cameras`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import torch

from voxnero.cameras.cameras import look_at_opencv  # noqa: F401  (re-exported: the rig's look-at)

if TYPE_CHECKING:
    from voxnero.cameras.cameras import Cameras

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
"""Azimuth increment of the Fibonacci lattice (radians)."""


def fibonacci_dirs(n: int, elev_range_deg: tuple[float, float] = (-20.0, 90.0),
                   offset: float = 0.5, phase: float = 0.0) -> np.ndarray:
    """Unit directions (n, 3) on a Fibonacci lattice over an elevation band (world, +Z up).

    Args:
        n: number of directions.
        elev_range_deg: (lowest, highest) elevation in degrees.
        offset: position of sample k inside its z-stratum, in [0, 1).
        phase: azimuth of the first sample (radians, measured from +X toward +Y).
    """
    z_lo, z_hi = (math.sin(math.radians(e)) for e in elev_range_deg)
    k = np.arange(n, dtype=np.float64)
    z = z_hi - (k + offset) / n * (z_hi - z_lo)
    rho = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = phase + k * GOLDEN_ANGLE
    return np.stack([rho * np.cos(phi), rho * np.sin(phi), z], -1)


def min_angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For each unit direction in ``a`` (N, 3), the angle in degrees to the nearest one in ``b``."""
    cos = np.clip(a @ b.T, -1.0, 1.0).max(axis=1)
    return np.degrees(np.arccos(cos))


def offset_lattice(n_test: int, train_dirs: np.ndarray, elev_range_deg: tuple[float, float],
                 seed: int = 0, tries: int = 256) -> tuple[np.ndarray, dict]:
    """Second Fibonacci lattice maximising the minimum angle to the train directions.

    Returns:
        (dirs (n_test, 3), info) with info = {offset, phase, min_angle_test_to_train_deg}.
    """
    if n_test == 0:
        return np.zeros((0, 3)), {"min_angle_test_to_train_deg": None}
    rng = np.random.default_rng(seed)
    best, best_info = None, {"min_angle_test_to_train_deg": -1.0}
    for _ in range(tries):
        offset, phase = float(rng.uniform(0.05, 0.95)), float(rng.uniform(0, 2 * math.pi))
        dirs = fibonacci_dirs(n_test, elev_range_deg, offset, phase)
        m = float(min_angles_deg(dirs, train_dirs).min()) if len(train_dirs) else 180.0
        if m > best_info["min_angle_test_to_train_deg"]:
            best = dirs
            best_info = {"offset": offset, "phase": phase, "min_angle_test_to_train_deg": m}
    return best, best_info


def focal_from_fov(width: int, fov_deg: float) -> float:
    """Focal length in pixels: f = 0.5 · W / tan(0.5 · fov)."""
    return 0.5 * width / math.tan(0.5 * math.radians(fov_deg))


def make_cameras(dirs: np.ndarray, resolution: int, fov_deg: float = 40.0,
                 distance: float = 4.0) -> Cameras:
    """Square pinhole cameras at ``distance · dirs`` (N, 3) looking at the origin, up +Z.

    Principal point at the image centre (W/2, H/2), pixel centres at (i + 0.5, j + 0.5).
    """
    from voxnero.cameras.cameras import Cameras

    f = focal_from_fov(resolution, fov_deg)
    K = torch.tensor([[f, 0.0, resolution / 2], [0.0, f, resolution / 2], [0.0, 0.0, 1.0]],
                     dtype=torch.float32).expand(len(dirs), 3, 3).clone()
    c2w = torch.as_tensor(look_at_opencv(distance * np.asarray(dirs)), dtype=torch.float32)
    return Cameras(K=K, c2w=c2w, width=resolution, height=resolution)


def camera_rig(n_train: int, n_test: int, resolution: int, fov_deg: float = 40.0,
               distance: float = 4.0, elev_range_deg: tuple[float, float] = (-20.0, 90.0),
               seed: int = 0) -> tuple[Cameras, Cameras, dict]:
    """Train and test cameras like the dev scenes.

    Returns:
        (train Cameras, test Cameras, info dict for scene_info.json).
    """
    train_dirs = fibonacci_dirs(n_train, elev_range_deg)
    test_dirs, info = offset_lattice(n_test, train_dirs, elev_range_deg, seed)
    return (make_cameras(train_dirs, resolution, fov_deg, distance),
            make_cameras(test_dirs, resolution, fov_deg, distance), info)
