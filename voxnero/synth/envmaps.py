"""Environment maps for synthetic scenes: procedural outdoor-like HDR, constant, or from a file.

All maps are equirectangular linear HDR radiance ``(H, W, 3)`` float32 with W = 2H, +Z up, in
the project's direction ↔ pixel convention (docs/ARCHITECTURE.md, implemented by
:mod:`voxnero.render.envmap`: pixel (col i, row j) is the radiance arriving from
``voxnero.render.envmap.pixel_dirs(H, W)[j, i]``).

The procedural map (seeded) has a sky gradient, a textured ground (checker tiles on the ground
plane, so that reflections show where the horizon and the ground are), a band of "buildings" of
random heights at the horizon, a few bright rectangular "windows" and a small bright sun disc.
Edges are smoothed over about one pixel so that the map is band-limited at its resolution.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from voxnero.errors import ConfigError


def _smoothstep(e0: float | np.ndarray, e1: float | np.ndarray, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


def procedural_envmap(height: int = 128, seed: int = 0, scale: float = 1.0,
                      sun_strength: float = 50.0, n_windows: int = 3) -> tuple[np.ndarray, dict]:
    """A seeded outdoor-like HDR environment.

    Args:
        height: H; the map is (H, 2H, 3).
        seed: seed of the random layout (sun position, windows, skyline).
        scale: exposure factor multiplying the whole map.
        sun_strength: peak radiance of the sun disc relative to the sky (before ``scale``).
        n_windows: number of bright rectangular windows near the horizon.

    Returns:
        (img (H, 2H, 3) float32 linear radiance, description dict with the layout for
        material.json).
    """
    from voxnero.render.latlong import pixel_dirs

    rng = np.random.default_rng(seed)
    H, W = height, 2 * height
    d = pixel_dirs(H, W).double().numpy()
    dz = np.clip(d[..., 2], -1.0, 1.0)
    elev = np.arcsin(dz)
    az = np.arctan2(d[..., 1], d[..., 0])
    px = math.pi / (H - 1)  # angular size of one row

    # sky: horizon haze -> blue zenith
    t = np.clip(elev / (math.pi / 2), 0.0, 1.0) ** 0.6
    horizon, zenith = np.array([1.0, 0.97, 0.92]), np.array([0.22, 0.42, 0.95])
    sky = (1 - t)[..., None] * horizon + t[..., None] * zenith

    # ground: checker tiles on the plane z = -1 seen from the origin
    dzn = np.minimum(dz, -1e-3)
    gx, gy = d[..., 0] / -dzn, d[..., 1] / -dzn
    checker = ((np.floor(gx / 0.5) + np.floor(gy / 0.5)) % 2).astype(np.float64)
    fade = np.exp(-np.hypot(gx, gy) / 20.0)  # tiles blur into a uniform tone far away
    g_val = 0.35 + 0.25 * (checker * fade + 0.5 * (1 - fade))
    ground = g_val[..., None] * np.array([0.55, 0.45, 0.35])
    w_sky = _smoothstep(-px, px, elev)[..., None]
    img = w_sky * sky + (1 - w_sky) * ground

    # skyline: buildings of random heights (grey, slightly varied) on top of the horizon
    n_bld = 24
    edges = np.sort(rng.uniform(-math.pi, math.pi, n_bld))
    heights = np.radians(rng.uniform(2.0, 14.0, n_bld))
    tones = rng.uniform(0.25, 0.6, n_bld)
    k = np.searchsorted(edges, az) % n_bld
    b_h, b_tone = heights[k], tones[k]
    in_bld = _smoothstep(px, -px, elev - b_h) * _smoothstep(-px, px, elev)
    img = img * (1 - in_bld[..., None]) + in_bld[..., None] * b_tone[..., None] * \
        np.array([0.8, 0.78, 0.75])

    layout: dict = {"kind": "procedural", "seed": seed, "scale": scale, "height": H,
                    "lobes": []}
    # windows: bright rectangles low in the sky
    for _ in range(n_windows):
        a0 = rng.uniform(-math.pi, math.pi)
        e0 = math.radians(rng.uniform(3.0, 25.0))
        hw, hh = math.radians(rng.uniform(4.0, 9.0)), math.radians(rng.uniform(3.0, 7.0))
        value = float(rng.uniform(8.0, 20.0))
        da = np.angle(np.exp(1j * (az - a0)))
        w = _smoothstep(hw + px, hw - px, np.abs(da)) * _smoothstep(hh + px, hh - px,
                                                                     np.abs(elev - e0))
        img = img * (1 - w[..., None]) + w[..., None] * value * np.array([1.0, 0.95, 0.85])
        layout["lobes"].append({"type": "window", "az_deg": math.degrees(a0),
                                "elev_deg": math.degrees(e0), "half_width_deg": math.degrees(hw),
                                "half_height_deg": math.degrees(hh), "value": value})

    # sun: a small disc with a soft edge
    if sun_strength > 0:
        s_az, s_el = rng.uniform(-math.pi, math.pi), math.radians(rng.uniform(25.0, 60.0))
        s_dir = np.array([math.cos(s_el) * math.cos(s_az), math.cos(s_el) * math.sin(s_az),
                          math.sin(s_el)])
        ang = np.arccos(np.clip(d @ s_dir, -1.0, 1.0))
        radius = max(math.radians(2.5), 1.5 * px)
        w = _smoothstep(radius + px, radius - px, ang)
        img = img + w[..., None] * sun_strength * np.array([1.0, 0.92, 0.8])
        layout["lobes"].append({"type": "sun", "dir": s_dir.tolist(),
                                "radius_deg": math.degrees(radius), "peak": sun_strength})
    return (img * scale).astype(np.float32), layout


def constant_envmap(height: int = 16, value: float | tuple[float, float, float] = 1.0
                    ) -> np.ndarray:
    """Uniform radiance ``value`` from every direction: (H, 2H, 3) float32 (white furnace)."""
    v = np.broadcast_to(np.asarray(value, dtype=np.float32), (3,))
    return np.broadcast_to(v, (height, 2 * height, 3)).copy()


def load_envmap(source: str, height: int = 128, seed: int = 0, scale: float = 1.0,
                constant: float = 1.0) -> tuple[np.ndarray, dict]:
    """The environment named by a config value.

    Args:
        source: ``"procedural"``, ``"constant"`` or a path to an ``.exr``/``.hdr`` file
            (read with :func:`voxnero.io.exr.read_envmap`, used at its own resolution).
        height: H of generated maps.
        seed: seed of the procedural layout.
        scale: exposure factor applied to every map (file maps included).
        constant: radiance of the ``"constant"`` map.

    Returns:
        (img (H, W, 3) float32 linear, description dict).
    """
    if source == "procedural":
        return procedural_envmap(height, seed, scale)
    if source == "constant":
        img = constant_envmap(height, constant * scale)
        return img, {"kind": "constant", "value": constant, "scale": scale}
    path = Path(source)
    if path.suffix.lower() not in (".exr", ".hdr"):
        raise ConfigError(f"env.source={source!r} is neither 'procedural', 'constant' nor an "
                          ".exr/.hdr file", fix="use env.source=procedural, env.source=constant "
                          "or env.source=/path/to/map.exr")
    from voxnero.io.exr import read_envmap

    img = read_envmap(path)
    if img.shape[1] != 2 * img.shape[0]:
        from voxnero.errors import DataError

        raise DataError(f"environment map is {img.shape[1]}x{img.shape[0]}, expected width = "
                        "2 x height (equirectangular)", path=path,
                        fix="resample it to a 2:1 lat-long map")
    return (img[..., :3] * scale).astype(np.float32), {"kind": "file", "file": str(path),
                                                       "scale": scale}

