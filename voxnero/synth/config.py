"""``SynthConfig``: settings of ``voxnero synth`` (the ``synth:`` section of a preset).

Defaults are the ``tiny`` scene (64², 24 train + 8 test views), the unit-test size; the presets
in ``configs/`` set larger ones. Overrides address nested keys, e.g.
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

from voxnero.errors import ConfigError

SHAPES = ("sphere", "torus", "two_spheres")
"""Names of the scene recipes."""


@dataclass
class MaterialConfig:
    """Uniform material: linear base colour, metalness, perceptual roughness r."""

    albedo: list[float] = field(default_factory=lambda: [0.8, 0.8, 0.8])
    metallic: float = 0.0
    roughness: float = 0.5

    def validate(self) -> None:
        if len(self.albedo) != 3 or not all(0.0 <= a <= 1.0 for a in self.albedo):
            raise ConfigError(f"material.albedo={self.albedo} must be 3 values in [0, 1]",
                              fix="write e.g. albedo=[0.8,0.2,0.1] (linear RGB)")
        for name in ("metallic", "roughness"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"material.{name}={getattr(self, name)} must be in [0, 1]")


@dataclass
class SphereConfig:
    """An analytic sphere (default: like the dev scene ``sphere_gold``)."""

    radius: float = 0.8
    center: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    material: MaterialConfig = field(default_factory=lambda: MaterialConfig(
        [1.0, 0.766, 0.336], 1.0, 0.1))


@dataclass
class TorusConfig:
    """A ring torus tilted about +X (default: like the dev scene ``torus_ceramic``)."""

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

    source: str = "procedural"
    height: int = 128
    seed: int = 0
    scale: float = 1.0
    constant: float = 1.0


@dataclass
class SynthConfig:
    """Everything that defines a synthetic scene (resolution, views, sampling, light, shapes)."""

    resolution: int = 64
    n_train: int = 24
    n_test: int = 8
    spp: int = 9
    max_depth: int = 3
    seed: int = 0
    fov_deg: float = 40.0
    distance: float = 4.0
    elevation_range_deg: list[float] = field(default_factory=lambda: [-20.0, 90.0])
    chunk: int = 1 << 19
    threads: int = 1
    write_train_exr: bool = False
    env: EnvConfig = field(default_factory=EnvConfig)
    sphere: SphereConfig = field(default_factory=SphereConfig)
    torus: TorusConfig = field(default_factory=TorusConfig)
    two_spheres: TwoSpheresConfig = field(default_factory=TwoSpheresConfig)

    def validate(self) -> None:
        """Raise :class:`ConfigError` for values that cannot make a scene."""
        checks = [(self.resolution >= 8, "resolution must be ≥ 8"),
                  (self.n_train >= 1 and self.n_test >= 0, "n_train ≥ 1 and n_test ≥ 0"),
                  (self.spp >= 1, "spp must be ≥ 1"),
                  (self.chunk >= 1024, "chunk must be ≥ 1024 rays"),
                  (self.threads >= 0, "threads must be ≥ 0 (0 = torch's default)"),
                  (self.max_depth >= 1, "max_depth must be ≥ 1 (1 = direct light only)"),
                  (0.0 < self.fov_deg < 170.0, "fov_deg must be in (0, 170)"),
                  (len(self.elevation_range_deg) == 2
                   and -90 <= self.elevation_range_deg[0] < self.elevation_range_deg[1] <= 90,
                   "elevation_range_deg must be [low, high] within [-90, 90]"),
                  (self.env.height >= 4, "env.height must be ≥ 4")]
        for ok, msg in checks:
            if not ok:
                raise ConfigError(f"synth: {msg}", fix="change the preset or the override")
        for m in (self.sphere.material, self.torus.material, self.two_spheres.a.material,
                  self.two_spheres.b.material):
            m.validate()
