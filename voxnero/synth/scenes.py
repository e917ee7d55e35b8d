"""The named scene recipes: shape name + config → geometry, materials and a description.

- ``sphere``: one analytic sphere (default gold, r 0.8, like the dev scene ``sphere_gold``);
- ``torus``: a ring torus tilted about +X (default blue ceramic R 0.62, r 0.26, 30°, like
  ``torus_ceramic``);
- ``two_spheres``: a mirror-like metal sphere and a diffuse coloured one that see each other in
  reflection (both inside the r = 0.9 bounding sphere).
"""

from __future__ import annotations

from voxnero.errors import ConfigError
from voxnero.synth.config import SHAPES, MaterialConfig, SphereConfig, SynthConfig
from voxnero.synth.materials import Material
from voxnero.synth.shapes import Sphere, Torus, Union

BOUND = 0.9
"""Every scene must fit in the origin-centred sphere of this radius (as the dev scenes)."""


def _material(m: MaterialConfig) -> Material:
    return Material(tuple(float(a) for a in m.albedo), float(m.metallic), float(m.roughness))


def _sphere(s: SphereConfig) -> Sphere:
    return Sphere(tuple(float(c) for c in s.center), float(s.radius))


def build_scene(shape: str, cfg: SynthConfig) -> tuple[Union, list[Material], dict]:
    """Geometry, per-object materials and a JSON description for ``shape``.

    Args:
        shape: one of :data:`voxnero.synth.config.SHAPES`.
        cfg: the scene config (its section for ``shape`` is used).

    Returns:
        (geometry, materials (one per object, same order), description for material.json
        with ``geometry`` and ``material`` entries named like the dev scenes').

    Raises:
        ConfigError: unknown shape, or an object outside the r = 0.9 bounding sphere.
    """
    if shape == "sphere":
        s = cfg.sphere
        geo = Union([_sphere(s)])
        mats = [_material(s.material)]
        desc = {"type": "analytic sphere", "radius": s.radius, "center": list(s.center)}
    elif shape == "torus":
        t = cfg.torus
        if not 0 < t.minor_radius < t.major_radius:
            raise ConfigError(f"torus: need 0 < minor_radius < major_radius, got "
                              f"{t.minor_radius}, {t.major_radius}", fix="a ring torus: r < R")
        geo = Union([Torus(t.major_radius, t.minor_radius, t.tilt_deg)])
        mats = [_material(t.material)]
        desc = {"type": "analytic torus", "major_radius": t.major_radius,
                "minor_radius": t.minor_radius, "tilt_deg": t.tilt_deg, "tilt_axis": "+X",
                "center": [0.0, 0.0, 0.0],
                "local_frame": "core circle in the local z = 0 plane; local -> world = "
                               "rotation by tilt_deg about +X"}
    elif shape == "two_spheres":
        a, b = cfg.two_spheres.a, cfg.two_spheres.b
        geo = Union([_sphere(a), _sphere(b)])
        mats = [_material(a.material), _material(b.material)]
        desc = {"type": "two analytic spheres",
                "objects": [{"name": "a", "radius": a.radius, "center": list(a.center)},
                            {"name": "b", "radius": b.radius, "center": list(b.center)}]}
    else:
        raise ConfigError(f"unknown synthetic shape {shape!r}", fix=f"use one of {list(SHAPES)}")
    if geo.bounding_radius() > BOUND + 1e-9:
        raise ConfigError(f"{shape}: the object reaches radius {geo.bounding_radius():.3f} > "
                          f"{BOUND}", fix="make it smaller or move it toward the origin")
    if len(mats) == 1:
        material = mats[0].to_dict()
    else:
        material = {"kind": "per_object",
                    "objects": [dict(name=o["name"], **m.to_dict())
                                for o, m in zip(desc["objects"], mats, strict=True)]}
    return geo, mats, {"geometry": desc, "material": material}
