"""``SynthConfig``: settings of ``voxnero synth`` (the ``synth:`` section of a preset).

Defaults are the ``standard`` preset's scene (256² like the dev scenes, 96 train + 16 test
views, 32 paths per pixel); the other presets in ``voxnero/configs/`` state what they change
(``tiny``: 64², 24 + 8 views, the unit-test size, and the ``synth`` command's default
preset). Overrides address nested keys, e.g.
``voxnero synth torus --preset tiny --out DIR torus.tilt_deg=45 env.seed=3 spp=64``.
Roughness values are perceptual r (GGX α = r²); albedo is linear RGB.

``chunk`` is the number of rays traced at once (~1 KB each); ``threads`` the torch CPU threads
used while rendering (restored afterwards). One thread is the default because the tracer's
element-wise ops on ~10⁵-ray tensors gain little from intra-op threads, and on a busy machine
the threads' synchronisation made the tiny sphere scene ~6x slower (33 s vs 5 s wall on the
shared 2-core dev machine at load ~11); 0 keeps torch's default.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from voxnero.config import BIG_COUNT, FRACTION, SEED, THREADS, Range, at_least, positive
from voxnero.errors import ConfigError

SHAPES = ("sphere", "torus", "two_spheres")
"""Names of the scene recipes."""


@dataclass
class MaterialConfig:
    """Uniform material: linear base colour, metalness, perceptual roughness r."""

    RANGES: ClassVar[dict[str, Range]] = {
        "albedo": FRACTION, "metallic": FRACTION, "roughness": FRACTION}

    albedo: list[float] = field(default_factory=lambda: [0.8, 0.8, 0.8])
    metallic: float = 0.0
    roughness: float = 0.5

    def validate(self) -> None:
        """Three albedo values (their range is in ``RANGES``)."""
        if len(self.albedo) != 3:
            raise ConfigError(f"material.albedo={self.albedo} must be 3 values in [0, 1]",
                              fix="write e.g. albedo=[0.8,0.2,0.1] (linear RGB)")


@dataclass
class SphereConfig:
    """An analytic sphere (default: like the dev scene ``sphere_gold``)."""

    RANGES: ClassVar[dict[str, Range]] = {"radius": positive(100.0),
                                          "center": Range(-100.0, 100.0)}

    radius: float = 0.8
    center: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    material: MaterialConfig = field(default_factory=lambda: MaterialConfig(
        [1.0, 0.766, 0.336], 1.0, 0.1))


@dataclass
class TorusConfig:
    """A ring torus tilted about +X (default: like the dev scene ``torus_ceramic``)."""

    RANGES: ClassVar[dict[str, Range]] = {
        "major_radius": positive(100.0), "minor_radius": positive(100.0),
        "tilt_deg": Range(-360.0, 360.0)}

    major_radius: float = 0.62
    minor_radius: float = 0.26
    tilt_deg: float = 30.0
    material: MaterialConfig = field(default_factory=lambda: MaterialConfig(
        [0.05, 0.18, 0.75], 0.0, 0.25))


@dataclass
class TwoSpheresConfig:
    """Two spheres that reflect each other: a mirror-like metal ``a``, a diffuse coloured ``b``."""

    a: SphereConfig = field(default_factory=lambda: SphereConfig(
        0.45, [-0.40, -0.10, 0.05], MaterialConfig([0.95, 0.93, 0.90], 1.0, 0.05)))
    b: SphereConfig = field(default_factory=lambda: SphereConfig(
        0.40, [0.45, 0.15, -0.05], MaterialConfig([0.80, 0.25, 0.10], 0.0, 0.6)))


@dataclass
class EnvConfig:
    """Environment light: ``source`` = "procedural", "constant" or a path to .exr/.hdr."""

    RANGES: ClassVar[dict[str, Range]] = {
        "height": at_least(4, 8192), "seed": SEED, "scale": Range(0.0, 1e6),
        "constant": Range(0.0, 1e6)}

    source: str = "procedural"
    height: int = 256
    seed: int = 0
    scale: float = 1.0
    constant: float = 1.0


@dataclass
class SynthConfig:
    """Everything that defines a synthetic scene (resolution, views, sampling, light, shapes)."""

    RANGES: ClassVar[dict[str, Range]] = {
        "resolution": at_least(8, 8192), "n_train": at_least(1, 100000),
        "n_test": at_least(0, 100000), "spp": at_least(1, 100000), "max_depth": at_least(1, 64),
        "seed": SEED, "fov_deg": Range(0.0, 170.0, lo_open=True, hi_open=True),
        "distance": positive(1e6), "elevation_range_deg": Range(-90.0, 90.0),
        "chunk": at_least(1024, BIG_COUNT), "threads": THREADS}
    """Allowed values (:func:`voxnero.config.check_numbers`), checked before ``validate``."""

    resolution: int = 256
    n_train: int = 96
    n_test: int = 16
    spp: int = 32
    max_depth: int = 3
    seed: int = 0
    fov_deg: float = 40.0
    distance: float = 4.0
    elevation_range_deg: list[float] = field(default_factory=lambda: [-20.0, 90.0])
    chunk: int = 1 << 17
    threads: int = 1
    write_train_exr: bool = False
    env: EnvConfig = field(default_factory=EnvConfig)
    sphere: SphereConfig = field(default_factory=SphereConfig)
    torus: TorusConfig = field(default_factory=TorusConfig)
    two_spheres: TwoSpheresConfig = field(default_factory=TwoSpheresConfig)

    def validate(self) -> None:
        """Raise :class:`ConfigError` for values that cannot make a scene (single values are
        checked against ``RANGES`` before)."""
        e = self.elevation_range_deg
        if not (len(e) == 2 and e[0] < e[1]):
            raise ConfigError(f"synth.elevation_range_deg={e} must be [low, high] with low < high",
                              fix="e.g. elevation_range_deg=[-20,90]")
        for m in (self.sphere.material, self.torus.material, self.two_spheres.a.material,
                  self.two_spheres.b.material):
            m.validate()
