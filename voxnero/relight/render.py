"""Relight driver: path-trace an :class:`~voxnero.asset.model.Asset` under an HDR env map.

Per pixel, ``spp`` primary rays through stratified jittered positions in the pixel footprint
(the box filter of the dev data) are cast against the mesh with Open3D
(:class:`voxnero.material.surface.Geometry`, the stage-2 ray caster). A ray that misses shows
the env map along it (the environment is at infinity). A hit is shaded by stage 2's light
paths on the mesh (:class:`voxnero.material.render.Paths`): the shading core's one MIS estimator
:func:`voxnero.render.estimator.shade_mc` (cosine + GGX-VNDF + env-map samples, power heuristic)
with Open3D visibility; light arriving along an occluded direction is the radiance of the
surface it hits, shaded the same way (up to ``bounces`` surface interactions); after the last
bounce it is the stage-2 split-sum estimate (:class:`voxnero.material.lights.IndirectLight`,
``tail="splitsum"``) or 0 (``tail="none"``). Stage 2 trains and evaluates with the same code.

Frames: the asset lives in the scene's input frame; rendering happens in the asset's own unit
frame (``Normalisation(centre of the bounding box, bounding radius)``, so ray offsets are
scale-free); cameras given in the input frame are mapped with the same similarity. The env map
is +Z up in its own frame; ``up`` names the world axis that is up for the map and ``yaw_deg``
turns it about that axis (``voxnero.render.envmap.rotate_dirs``).

Outputs are LINEAR radiance times ``2**exposure``; PNGs are ``round(255 · sRGB(clip(L)))``
like the dev data.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch
from torch import Tensor

from voxnero.cameras.rays import pixel_samples
from voxnero.config import BIG_COUNT, SEED, THREADS, Range, at_least, positive
from voxnero.errors import ConfigError, DataError


@dataclass
class OrbitConfig:
    """Turntable cameras (``voxnero relight --orbit``)."""

    RANGES: ClassVar[dict[str, Range]] = {
        "frames": at_least(1, 100000), "elevation_deg": Range(-90.0, 90.0),
        "distance": Range(0.0, 1e9), "fov_deg": Range(0.0, 180.0, lo_open=True, hi_open=True),
        "size": at_least(1, 16384)}

    frames: int = 36
    elevation_deg: float = 20.0
    distance: float = 0.0
    """Camera distance in input-frame units; 0 = the bounding sphere fills 80 % of the view."""
    fov_deg: float = 40.0
    size: int = 256
    """Image width = height in pixels."""


@dataclass
class RelightConfig:
    """Monte Carlo settings and outputs of ``voxnero relight`` (section ``relight:``)."""

    RANGES: ClassVar[dict[str, Range]] = {
        "spp": at_least(1, 100000), "dirs": at_least(1, 1000), "bounce_dirs": at_least(1, 1000),
        "bounces": at_least(1, 64), "scale": positive(16.0), "exposure": Range(-20.0, 20.0),
        "yaw_deg": Range(-360.0, 360.0), "env_scale": Range(0.0, 1e6),
        "views": at_least(1, also=(-1,)), "chunk": at_least(1, BIG_COUNT), "seed": SEED,
        "threads": THREADS}
    """Allowed values (:func:`voxnero.config.check_numbers`), checked before ``validate``.
    ``exposure`` within ±20 stops (x1e6): a 1.0 radiance 2^16 times brighter already leaves
    the half-float range (65504) that EXR viewers and most HDR pipelines use."""

    spp: int = 16
    """Primary rays per pixel (stratified in the pixel footprint: box filter, antialiasing)."""
    dirs: int = 3
    """Shading directions per primary hit, split evenly over the cosine / GGX / env strategies
    (below 3 the last strategies get none: 1 = cosine only, useless on glossy surfaces)."""
    bounce_dirs: int = 3
    """Shading directions per secondary hit (each path branches into this many; >= 3 keeps
    all three strategies)."""
    bounces: int = 2
    """Surface interactions traced by Monte Carlo (1 = direct light with shadows)."""
    tail: str = "splitsum"
    """Light along occluded directions after the last bounce: 'splitsum' (stage-2
    IndirectLight estimate of the hit's radiance) or 'none' (0)."""
    strategy: str = "mis"
    """shade_mc strategy: mis, balance, cosine, ggx, env."""
    scale: float = 1.0
    """Resolution scale of the cameras (0.5 = half width and height)."""
    exposure: float = 0.0
    """Exposure in stops: every output radiance is multiplied by 2**exposure."""
    yaw_deg: float = 0.0
    """Rotation of the env map about the up axis (degrees)."""
    env_scale: float = 1.0
    """Multiplier of the env map's radiance as read."""
    split: str = "test"
    """Split of --scene whose cameras are used."""
    views: int = -1
    """How many of the cameras to render (evenly spread); -1 = all."""
    chunk: int = 65536
    """Primary rays cast and shaded at once."""
    seed: int = 0
    threads: int = 1
    """torch CPU threads (0 = torch's default). On the busy shared 2-core dev machine two
    threads ran a view 10-25x slower than one (Open3D's ray casts use their own threads)."""
    png: bool = True
    exr: bool = True
    orbit: OrbitConfig = field(default_factory=OrbitConfig)

    def validate(self) -> None:
        """Raise ConfigError on impossible choices (numbers are checked against ``RANGES``
        before)."""
        from voxnero.render.estimator import STRATEGIES

        if self.tail not in ("splitsum", "none"):
            raise ConfigError(f"relight.tail={self.tail!r}", fix="use splitsum or none")
        if self.strategy not in STRATEGIES:
            raise ConfigError(f"relight.strategy={self.strategy!r}",
                              fix=f"use one of {STRATEGIES}")


_UP_NAMES = {(0, 0, 1): "z", (0, 1, 0): "y", (0, -1, 0): "-y", (1, 0, 0): "x", (0, 0, -1): "-z"}


def up_axis_name(up: np.ndarray) -> str:
    """Name of an axis-aligned up vector for ``voxnero.render.envmap.rotate_dirs``.

    Args:
        up: (3,) unit vector, one of ±Z, ±Y, +X.

    Raises:
        ConfigError: another direction (not supported by the env-map rotations).
    """
    key = tuple(int(round(float(c))) for c in np.asarray(up, dtype=np.float64))
    if key not in _UP_NAMES or abs(np.linalg.norm(up) - 1) > 1e-3 or \
            np.abs(np.asarray(up) - np.asarray(key)).max() > 1e-3:
        raise ConfigError(f"up axis {np.asarray(up).tolist()} is not axis-aligned",
                          fix="relighting supports scenes whose up axis is ±Z, ±Y or +X")
    return _UP_NAMES[key]


def world_frame_map(env, height: int | None = None) -> Tensor:
    """The env map resampled so that a plain ``envmap_lookup`` with WORLD directions sees the
    rotated map (for code that takes a bare image, e.g. the stage-2 indirect estimate).

    Args:
        env: :class:`voxnero.render.envmap.EnvMap` (with up / yaw).
        height: output height (default the map's).

    Returns:
        (H, 2H, 3) linear map; exactly ``env.img`` when the rotation is the identity.
    """
    from voxnero.render.envmap import pixel_dirs

    if env._identity and height is None:
        return env.img
    H = height or env.img.shape[0]
    d = pixel_dirs(H, 2 * H, device=env.device)
    return env.lookup(d.reshape(-1, 3)).reshape(H, 2 * H, 3)


class Relighter:
    """Path tracer of one asset under one env map (see the module docstring).

    Args:
        asset: the :class:`voxnero.asset.model.Asset` (input frame).
        env: :class:`voxnero.render.envmap.EnvMap` already oriented (up, yaw) for the world.
        cfg: :class:`RelightConfig`.
        device: torch device of the shading (ray casts run in Open3D on the CPU).
    """

    def __init__(self, asset, env, cfg: RelightConfig, device: torch.device | str = "cpu"):
        from voxnero.data.scene import Normalisation
        from voxnero.material.lights import IndirectLight
        from voxnero.material.render import Bounces, Paths, Strategies
        from voxnero.material.surface import Geometry
        from voxnero.render.estimator import split_counts

        self.asset, self.env, self.cfg = asset, env, cfg
        self.device = torch.device(device)
        c, r = asset.bounds()
        self.norm = Normalisation(c, max(r, 1e-9))
        self.geom = Geometry.from_legacy(asset.legacy_mesh(self.norm))
        self.tail = IndirectLight(world_frame_map(env), diffuse=asset.diffuse) \
            if cfg.tail == "splitsum" else None
        self.exposure = 2.0 ** cfg.exposure
        self.spp = Strategies(*split_counts(cfg.dirs, cfg.strategy, True))
        bounce_spp = Strategies(*split_counts(cfg.bounce_dirs, cfg.strategy, True))
        mode = "traced" if cfg.bounces > 1 or self.tail is not None else "off"
        # bounces counts surface interactions: cfg.bounces - 1 of them after the primary hit
        self.paths = Paths(self.geom.to(self.device), self._material, env.lookup, env, mode,
                           self.tail,
                           Bounces(cfg.bounces - 1, 0, 1.0, bounce_spp, one_sample=False),
                           strategy=cfg.strategy, diffuse=asset.diffuse)

    # -- shading
    def _material(self, tri: Tensor, bary: Tensor, x: Tensor | None = None
                  ) -> tuple[Tensor, Tensor, Tensor]:
        a, m, r = self.asset.material_at(tri.cpu(), bary.cpu())
        return a.to(self.device), m.to(self.device), r.to(self.device)

    def shade_hits(self, tri: Tensor, bary: Tensor, v: Tensor, depth: int,
                   generator: torch.Generator | None = None) -> Tensor:
        """Outgoing radiance of surface hits toward ``v`` (stage 2's :class:`Paths`: the
        shading core's estimator, Open3D visibility, traced bounces, then the tail).

        Args:
            tri: (N,) long hit triangles; bary: (N, 3) barycentrics.
            v: (N, 3) unit directions toward the viewer / previous vertex.
            depth: 0 for primary hits.
            generator: random stream.

        Returns:
            (N, 3) linear radiance (before exposure).
        """
        g = self.paths.geom
        tri, bary = tri.to(self.device), bary.to(self.device)
        x, n = g.points_at(tri, bary), g.normals_at(tri, bary)
        self.paths.gen = generator
        spp = self.spp if depth == 0 else self.paths.bounces.spp
        return self.paths.shade(tri, bary, x, n, v.to(self.device), spp, depth)

    def radiance(self, o: Tensor, d: Tensor, generator: torch.Generator | None = None
                 ) -> tuple[Tensor, Tensor]:
        """Radiance along camera rays (unit frame of the renderer).

        Args:
            o: (N, 3) origins; d: (N, 3) unit directions.

        Returns:
            (N, 3) linear radiance (before exposure) and (N,) bool hit mask.
        """
        _, tri, bary = self.geom.cast(o.cpu(), d.cpu())
        out = self.env.lookup(d.to(self.device))
        hit = tri >= 0
        if hit.any():
            idx = hit.nonzero()[:, 0]
            val = self.shade_hits(tri[idx], bary[idx], -d[idx].to(self.device), 0, generator)
            out = out.index_put((idx.to(self.device),), val)
        return out, hit

    # -- images
    def unit_cameras(self, cameras):
        """Cameras (input frame) mapped into the renderer's unit frame."""
        from voxnero.cameras.cameras import Cameras

        c2w = cameras.c2w.clone()
        c2w[:, :3, 3] = self.norm.to_unit(c2w[:, :3, 3].double()).float()
        return Cameras(cameras.K.clone(), c2w, cameras.width, cameras.height)

    def render(self, cameras, index: int, generator: torch.Generator | None = None,
               window: tuple[int, int, int, int] | None = None,
               progress=None) -> dict[str, Tensor]:
        """Render one view.

        Args:
            cameras: :class:`voxnero.cameras.cameras.Cameras` in the INPUT frame.
            index: which camera.
            generator: random stream (pixel jitter and shading samples).
            window: (row0, col0, rows, cols) crop of the image (default all of it).
            progress: optional tqdm bar, advanced by the number of pixels done.

        Returns:
            ``rgb`` (rows, cols, 3) linear radiance × 2**exposure (box-filtered pixel averages),
            ``alpha`` (rows, cols) fraction of primary rays hitting the asset.
        """
        from voxnero.cameras.rays import pixel_rays

        cams = self.unit_cameras(cameras[index])
        H, W = cams.height, cams.width
        spp = self.cfg.spp
        pix = pixel_samples(H, W, spp, generator, window)  # (h, w, spp, 2)
        h, w = pix.shape[:2]
        flat = pix.reshape(-1, 2)
        rgb = torch.zeros(flat.shape[0], 3, device=self.device)
        hit = torch.zeros(flat.shape[0], dtype=torch.bool)
        step = max(spp, (self.cfg.chunk // spp) * spp)
        for s in range(0, flat.shape[0], step):
            p = flat[s:s + step]
            o, d = pixel_rays(cams, torch.zeros(p.shape[0], dtype=torch.long), p)
            with torch.no_grad():
                rgb[s:s + step], hit[s:s + step] = self.radiance(o, d, generator)
            if progress is not None:
                progress.update(p.shape[0] // spp)
        rgb = rgb.reshape(h, w, spp, 3).mean(2) * self.exposure
        alpha = hit.reshape(h, w, spp).float().mean(2)
        return {"rgb": rgb.cpu(), "alpha": alpha}


MAX_RADIANCE = 1e20
"""Largest env radiance × ``2**exposure`` relit: a sun in a real HDR map is ~1e5; far above
this the Monte Carlo sums (and their squares) leave float32 (3.4e38) and an EXR would hold
Inf."""


def load_env(path, up: np.ndarray, cfg: RelightConfig, device: torch.device | str = "cpu"):
    """Read an equirectangular ``.exr``/``.hdr`` map as an oriented :class:`EnvMap`.

    Args:
        path: map file (+Z up in its own frame, dev-scene convention).
        up: (3,) world up axis of the asset's frame.
        cfg: uses ``yaw_deg``, ``env_scale`` and ``exposure``.
        device: torch device.

    Raises:
        DataError: the map scaled by ``env_scale`` and ``2**exposure`` exceeds
            :data:`MAX_RADIANCE` (naming the file; unreadable or NaN/Inf maps are refused by
            ``voxnero.io.exr.read_envmap``).
    """
    from voxnero.render.envmap import EnvMap

    env = EnvMap.from_file(path, up=up_axis_name(up), yaw_deg=cfg.yaw_deg,
                           scale=cfg.env_scale, device=device)
    peak = float(env.img.max()) * 2.0 ** cfg.exposure
    if not peak <= MAX_RADIANCE:  # also catches inf and NaN
        raise DataError(f"env map radiance up to {float(env.img.max()):.3g} (env_scale="
                        f"{cfg.env_scale:g}) at exposure {cfg.exposure:g} reaches {peak:.3g}, "
                        f"above {MAX_RADIANCE:g}: the renders would overflow to Inf", path=path,
                        fix="scale the map down (env_scale=1e-3 ...) or lower exposure")
    return env

