"""Environment maps of the corpus: procedural skies with a small sun, procedural rooms, and the
maps of the dev scenes (../shared/data/*/gt).

Convention (../shared/data/README.md): equirectangular, 512 × 256 (W × H), linear RGB radiance,
+Z up; pixel (column i, row j) is the radiance arriving from
``theta = pi j / (H - 1)``, ``phi = 2 pi (i + 0.5) / W``,
``d = (sin theta sin phi, sin theta cos phi, cos theta)`` (d points from the object outward).
Mitsuba's ``envmap`` emitter with ``to_world = rotate(+X, 90°)`` reads exactly this map.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

WIDTH, HEIGHT = 512, 256


def directions(width: int = WIDTH, height: int = HEIGHT) -> np.ndarray:
    """``(H, W, 3)`` unit world directions of the env-map pixels (convention above)."""
    theta = math.pi * np.arange(height) / (height - 1)
    phi = 2 * math.pi * (np.arange(width) + 0.5) / width
    t, p = np.meshgrid(theta, phi, indexing="ij")
    return np.stack([np.sin(t) * np.sin(p), np.sin(t) * np.cos(p), np.cos(t)], axis=-1)


def lookup(env: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Bilinear radiance of ``env (H, W, 3)`` along unit world directions ``d (..., 3)``.

    ``u = atan2(dx, dy) / 2pi`` (periodic), ``v = arccos(dz) / pi``; column ``u W - 0.5``, row
    ``v (H - 1)`` (Mitsuba's envmap emitter; used to check the rendered backgrounds).
    """
    h, w = env.shape[:2]
    u = (np.arctan2(d[..., 0], d[..., 1]) / (2 * math.pi)) % 1.0
    v = np.arccos(np.clip(d[..., 2], -1.0, 1.0)) / math.pi
    x, y = u * w - 0.5, v * (h - 1)
    x0, y0 = np.floor(x).astype(int), np.clip(np.floor(y).astype(int), 0, h - 2)
    fx, fy = (x - x0)[..., None], np.clip(y - y0, 0.0, 1.0)[..., None]
    x0w, x1w = x0 % w, (x0 + 1) % w
    top = env[y0, x0w] * (1 - fx) + env[y0, x1w] * fx
    bot = env[y0 + 1, x0w] * (1 - fx) + env[y0 + 1, x1w] * fx
    return top * (1 - fy) + bot * fy


def _noise(rng: np.random.Generator, d: np.ndarray, octaves: int = 4, freq: float = 3.0
           ) -> np.ndarray:
    """Smooth value noise in [0, 1] on the sphere: a sum of random sinusoids of ``d``."""
    out = np.zeros(d.shape[:-1])
    amp, total = 1.0, 0.0
    for o in range(octaves):
        for _ in range(6):
            k = rng.normal(size=3)
            k *= freq * (2 ** o) / np.linalg.norm(k)
            out += amp * np.sin(d @ k + rng.uniform(0, 2 * math.pi))
            total += amp
        amp *= 0.5
    return 0.5 + 0.5 * out / math.sqrt(total * 2)


def sun_sky(seed: int, sun_elev_deg: float, sun_azim_deg: float, sun_ratio: float = 3e4,
            sun_radius_deg: float = 0.8) -> np.ndarray:
    """An outdoor sky with clouds, a textured ground and a small bright sun.

    The sun is a disc of angular radius ``sun_radius_deg`` whose radiance is ``sun_ratio`` times
    the median of the map (so ≥ 10⁴ : 1 for the default), drawn with supersampled coverage so
    its energy does not depend on where it falls on the pixel grid.

    Returns:
        ``(256, 512, 3)`` float32 linear radiance.
    """
    rng = np.random.default_rng(seed)
    d = directions()
    z = d[..., 2:3]
    zenith, horizon = np.array([0.18, 0.35, 0.85]), np.array([0.75, 0.82, 0.92])
    sky = horizon + (zenith - horizon) * np.sqrt(np.clip(z, 0, 1))
    cloud = np.clip(_noise(rng, d, freq=4.0) * 2.2 - 1.1, 0, 1)[..., None]
    sky = sky * (1 - cloud) + np.array([1.0, 1.0, 1.0]) * 1.1 * cloud
    ground_tex = 0.6 + 0.8 * _noise(rng, d, freq=12.0)[..., None]
    ground = np.array([0.22, 0.19, 0.14]) * ground_tex
    env = np.where(z >= 0, sky, ground) * 1.2
    e, a = math.radians(sun_elev_deg), math.radians(sun_azim_deg)
    sun = np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])
    env = env + _disc(sun, math.radians(sun_radius_deg)) * np.array([1.0, 0.93, 0.8]) \
        * sun_ratio * float(np.median(env))
    return env.astype(np.float32)


def _disc(axis: np.ndarray, radius: float, sub: int = 8) -> np.ndarray:
    """``(H, W, 1)`` fraction of each env pixel's footprint inside the cone (``axis``, ``radius``),
    by ``sub``² sub-pixel samples."""
    h, w = HEIGHT, WIDTH
    cover = np.zeros((h, w))
    for sy in range(sub):
        for sx in range(sub):
            theta = math.pi * np.clip(np.arange(h) + (sy + 0.5) / sub - 0.5, 0, h - 1) / (h - 1)
            phi = 2 * math.pi * (np.arange(w) + (sx + 0.5) / sub) / w
            t, p = np.meshgrid(theta, phi, indexing="ij")
            d = np.stack([np.sin(t) * np.sin(p), np.sin(t) * np.cos(p), np.cos(t)], axis=-1)
            cover += (d @ axis) > math.cos(radius)
    return (cover / sub ** 2)[..., None]


def room(seed: int, size: tuple[float, float, float] = (6.0, 8.0, 3.2),
         centre: tuple[float, float, float] = (0.7, -0.9, 1.0)) -> np.ndarray:
    """An indoor room seen from ``centre`` (metres from the room's floor centre): a checker
    floor, striped walls, two ceiling light panels (≈ 6) and a window (≈ 3); walls ≈ 0.2.

    The panels are set so that a white diffuse surface under them reads about 0.9 (not clipped
    in the 8-bit photos).

    Returns:
        ``(256, 512, 3)`` float32 linear radiance.
    """
    rng = np.random.default_rng(seed)
    d = directions()
    half = np.array([size[0] / 2, size[1] / 2])
    o = np.array(centre, dtype=float)
    # distance to each of the six planes of the box [-hx,hx]x[-hy,hy]x[0,H] along d
    with np.errstate(divide="ignore", invalid="ignore"):
        tx = np.where(d[..., 0] > 0, (half[0] - o[0]) / d[..., 0], (-half[0] - o[0]) / d[..., 0])
        ty = np.where(d[..., 1] > 0, (half[1] - o[1]) / d[..., 1], (-half[1] - o[1]) / d[..., 1])
        tz = np.where(d[..., 2] > 0, (size[2] - o[2]) / d[..., 2], -o[2] / d[..., 2])
    t = np.minimum(np.minimum(np.abs(tx), np.abs(ty)), np.abs(tz))
    p = o + d * t[..., None]
    which = np.argmin(np.stack([np.abs(tx), np.abs(ty), np.abs(tz)]), axis=0)
    wall_cols = rng.uniform(0.15, 0.35, size=(4, 3))
    env = np.zeros(d.shape)
    # walls: horizontal stripes + a dado band, colour per wall
    for axis in (0, 1):
        for sgn_i, sgn in enumerate((-1, 1)):
            sel = (which == axis) & (np.sign(d[..., axis]) == sgn)
            col = wall_cols[2 * axis + sgn_i]
            stripe = 0.85 + 0.15 * (np.floor(p[..., 2] * 4) % 2)
            dado = np.where(p[..., 2] < 0.9, 0.6, 1.0)
            env[sel] = (col * (stripe * dado)[..., None])[sel]
    floor = (which == 2) & (d[..., 2] < 0)
    check = (np.floor(p[..., 0] * 1.5) + np.floor(p[..., 1] * 1.5)) % 2
    env[floor] = (np.array([0.30, 0.20, 0.12]) * (0.6 + 0.4 * check)[..., None])[floor]
    ceil = (which == 2) & (d[..., 2] > 0)
    env[ceil] = 0.5
    for cx in (-1.2, 1.4):
        panel = ceil & (np.abs(p[..., 0] - cx) < 0.5) & (np.abs(p[..., 1]) < 1.2)
        env[panel] = np.array([6.0, 5.7, 5.1])
    window = ((which == 1) & (d[..., 1] > 0) & (np.abs(p[..., 0] - 0.5) < 1.2)
              & (p[..., 2] > 1.0) & (p[..., 2] < 2.4))
    env[window] = np.array([2.4, 2.9, 3.6])
    return env.astype(np.float32)


def shared_map(shared_data: Path, name: str) -> np.ndarray:
    """A map of the dev scenes: ``warehouse`` (the training map) or ``venice_sunset`` /
    ``proc_courtyard`` (their relight maps), read from ``sphere_gold/gt``."""
    from voxnero.io.exr import read_exr

    gt = Path(shared_data) / "sphere_gold" / "gt"
    path = gt / ("envmap.exr" if name == "warehouse" else f"envmap_{name}.exr")
    return read_exr(path)[..., :3].astype(np.float32)


SOURCES = {
    "warehouse": "Mitsuba 3 test data principled_envmap.hdr (indoor hall), as shipped in "
                 "../shared/data/sphere_gold/gt/envmap.exr",
    "venice_sunset": "Poly Haven 'Venice Sunset' (CC0), as shipped in "
                     "../shared/data/sphere_gold/gt/envmap_venice_sunset.exr",
    "proc_courtyard": "procedural (dev data), ../shared/data/sphere_gold/gt/"
                      "envmap_proc_courtyard.exr",
    "sky_noon": "procedural (this tool, seed 1): sky, clouds, ground, sun 0.8° at 62° "
                "elevation, 3e4 x median (CC0)",
    "sky_low": "procedural (this tool, seed 2): sky, clouds, ground, sun 0.8° at 22° "
               "elevation, 3e4 x median (CC0)",
    "room_a": "procedural (this tool, seed 3): room 6x8x3.2 m, two ceiling panels, a window "
              "(CC0)",
    "room_b": "procedural (this tool, seed 4): room 5x6x2.8 m seen off-centre (CC0)",
}
"""Provenance and licence of every map the corpus uses (written to each scene's JSON)."""


def make(name: str, shared_data: Path) -> np.ndarray:
    """The env map called ``name`` (a key of :data:`SOURCES`), ``(256, 512, 3)`` float32."""
    if name in ("warehouse", "venice_sunset", "proc_courtyard"):
        return shared_map(shared_data, name)
    return {"sky_noon": lambda: sun_sky(1, 62.0, 40.0),
            "sky_low": lambda: sun_sky(2, 22.0, 200.0),
            "room_a": lambda: room(3),
            "room_b": lambda: room(4, size=(5.0, 6.0, 2.8), centre=(-1.1, 0.8, 0.9)),
            }[name]()
