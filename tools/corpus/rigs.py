"""Camera rigs of the corpus: where the 96 training and 16 test cameras stand.

All cameras look at the origin from a distance chosen so that the object's bounding sphere
fills a given fraction of the image width. Matrices are OpenGL/Blender camera-to-world
(columns: image right, image up, backwards, centre), built by ``look_at(eye, 0, up=+Z)`` with
+Y as up for a camera straight above or below.
"""

from __future__ import annotations

import math

import numpy as np

FOV_X_DEG = 40.0
"""Horizontal (= vertical, square images) field of view of every corpus camera."""


def distance_for_fill(radius: float, fill: float, fov_deg: float = FOV_X_DEG) -> float:
    """Camera distance at which a sphere of ``radius`` spans ``fill`` of the image width."""
    half = math.atan(fill * math.tan(math.radians(fov_deg) / 2))
    return radius / math.sin(half)


def pixel_size(distance: float, width: int, fov_deg: float = FOV_X_DEG) -> float:
    """World size of one pixel at the origin seen from ``distance`` (units / px)."""
    return 2 * distance * math.tan(math.radians(fov_deg) / 2) / width


def look_at_gl(eyes: np.ndarray) -> np.ndarray:
    """``(N, 4, 4)`` OpenGL camera-to-world matrices looking from ``eyes (N, 3)`` at the origin."""
    eyes = np.asarray(eyes, dtype=np.float64)
    back = eyes / np.linalg.norm(eyes, axis=1, keepdims=True)
    up = np.tile([0.0, 0.0, 1.0], (len(eyes), 1))
    polar = np.abs(back[:, 2]) > 1 - 1e-9
    up[polar] = [0.0, 1.0, 0.0]
    right = np.cross(up, back)
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    true_up = np.cross(back, right)
    c2w = np.tile(np.eye(4), (len(eyes), 1, 1))
    c2w[:, :3, 0], c2w[:, :3, 1], c2w[:, :3, 2], c2w[:, :3, 3] = right, true_up, back, eyes
    return c2w


def pixel_directions(c2w_gl: np.ndarray, focal: float, width: int, height: int) -> np.ndarray:
    """``(H, W, 3)`` world unit directions through the pixel centres of an OpenGL camera
    (``c2w_gl`` (4, 4); pixel (i, j) centre at (i + 0.5, j + 0.5), principal point at the image
    centre, square pixels of ``focal`` px)."""
    j, i = np.mgrid[0:height, 0:width]
    cam = np.stack([(i + 0.5 - width / 2) / focal, -(j + 0.5 - height / 2) / focal,
                    -np.ones_like(i, float)], axis=-1)
    d = cam @ np.asarray(c2w_gl, dtype=np.float64)[:3, :3].T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def fibonacci(n: int, elev_min_deg: float, elev_max_deg: float, phase: float = 0.0,
              offset: float = 0.5) -> np.ndarray:
    """``(n, 3)`` unit directions, area-uniform over the elevation band, golden-angle azimuths."""
    z0, z1 = math.sin(math.radians(elev_min_deg)), math.sin(math.radians(elev_max_deg))
    k = np.arange(n) + offset
    z = z0 + (z1 - z0) * k / n
    phi = phase + k * math.pi * (3 - math.sqrt(5))
    r = np.sqrt(1 - z ** 2)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def rings(n: int, elevations_deg: tuple[float, ...], top: bool = True) -> np.ndarray:
    """``(n, 3)`` unit directions on rings of constant elevation (counts ∝ the ring's
    circumference), plus one camera straight above when ``top``."""
    n_ring = n - int(top)
    w = np.array([math.cos(math.radians(e)) for e in elevations_deg])
    counts = np.floor(w / w.sum() * n_ring).astype(int)
    counts[np.argsort(-w)[: n_ring - counts.sum()]] += 1
    out = []
    for i, (e, c) in enumerate(zip(elevations_deg, counts, strict=True)):
        el = math.radians(e)
        phi = 2 * math.pi * (np.arange(c) + 0.5 * (i % 2)) / c
        out.append(np.stack([math.cos(el) * np.cos(phi), math.cos(el) * np.sin(phi),
                             np.full(c, math.sin(el))], axis=1))
    if top:
        out.append(np.array([[0.0, 0.0, 1.0]]))
    return np.concatenate(out)


RIGS = {
    "band": "Fibonacci lattice over elevations -20°..+90° (the dev scenes' rig)",
    "full": "Fibonacci lattice over elevations -65°..+90° (views from below)",
    "rings": "rings at -40°, -10°, 20°, 50°, 75° and one camera straight above (90°)",
}


def train_directions(rig: str, n: int = 96) -> np.ndarray:
    """``(n, 3)`` unit directions from the origin to the training cameras of ``rig``."""
    if rig == "band":
        return fibonacci(n, -20.0, 90.0)
    if rig == "full":
        return fibonacci(n, -65.0, 90.0)
    if rig == "rings":
        return rings(n, (-40.0, -10.0, 20.0, 50.0, 75.0), top=True)
    raise ValueError(f"unknown rig {rig!r}; one of {sorted(RIGS)}")


def test_directions(rig: str, train: np.ndarray, n: int = 16, seed: int = 0,
                    tries: int = 200) -> tuple[np.ndarray, float]:
    """``(n, 3)`` test directions over the rig's elevation band, as far from every training
    direction as a seeded search over lattice phases finds; and that minimum angle (degrees)."""
    lo = {"band": -20.0, "full": -65.0, "rings": -40.0}[rig]
    rng = np.random.default_rng(seed)
    best, best_angle = None, -1.0
    for _ in range(tries):
        d = fibonacci(n, lo, 80.0, phase=rng.uniform(0, 2 * math.pi), offset=rng.uniform(0, 1))
        angle = math.degrees(math.acos(min(1.0, float((d @ train.T).max()))))
        if angle > best_angle:
            best, best_angle = d, angle
    return best, best_angle
