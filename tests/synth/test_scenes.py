"""Tests of voxnero/synth/scenes.py and config.py: recipes, materials, validation."""

from __future__ import annotations

import pytest

from voxnero.config import from_dict, resolve
from voxnero.errors import ConfigError
from voxnero.synth.config import SynthConfig
from voxnero.synth.scenes import BOUND, build_scene
from voxnero.synth.shapes import Sphere, Torus


def test_recipes_match_the_dev_scenes_and_fit_the_bound():
    cfg = SynthConfig()
    geo, mats, desc = build_scene("sphere", cfg)
    assert isinstance(geo.shapes[0], Sphere) and geo.shapes[0].radius == 0.8
    assert desc["material"]["base_color"] == [1.0, 0.766, 0.336]
    assert desc["material"]["metallic"] == 1.0 and desc["material"]["roughness"] == 0.1
    geo, mats, desc = build_scene("torus", cfg)
    t = geo.shapes[0]
    assert isinstance(t, Torus) and (t.major_radius, t.minor_radius, t.tilt_deg) == (0.62, 0.26,
                                                                                      30.0)
    geo, mats, desc = build_scene("two_spheres", cfg)
    a, b = geo.shapes
    assert mats[0].metallic == 1.0 and mats[0].roughness <= 0.1  # mirror-like
    assert mats[1].metallic == 0.0 and mats[1].albedo != mats[0].albedo  # diffuse, coloured
    gap = sum((p - q) ** 2 for p, q in zip(a.center, b.center, strict=True)) ** 0.5
    assert gap > a.radius + b.radius  # separate objects
    assert [o["name"] for o in desc["material"]["objects"]] == ["a", "b"]
    for name in ("sphere", "torus", "two_spheres"):
        assert build_scene(name, cfg)[0].bounding_radius() <= BOUND


def test_overrides_reach_nested_keys_and_bad_values_are_refused(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text("synth: {resolution: 32}\n")
    cfg = resolve(SynthConfig, "synth", str(p), ["torus.tilt_deg=10",
                                                 "two_spheres.b.material.albedo=[0.1,0.9,0.1]"])
    assert cfg.resolution == 32 and cfg.torus.tilt_deg == 10.0
    assert build_scene("two_spheres", cfg)[1][1].albedo == (0.1, 0.9, 0.1)
    with pytest.raises(ConfigError, match="albedo"):
        from_dict(SynthConfig, {"sphere": {"material": {"albedo": [1, 2]}}})
    with pytest.raises(ConfigError, match="max_depth"):
        from_dict(SynthConfig, {"max_depth": 0})
    with pytest.raises(ConfigError, match="minor_radius"):
        build_scene("torus", from_dict(SynthConfig, {"torus": {"minor_radius": 0.7}}))
    with pytest.raises(ConfigError, match="unknown synthetic shape"):
        build_scene("cube", SynthConfig())


@pytest.mark.parametrize("preset", ["tiny", "preview", "standard", "quality"])
def test_presets_have_a_valid_synth_section(preset):
    cfg = resolve(SynthConfig, "synth", preset, [])
    assert cfg.resolution >= 64 and cfg.n_train >= 24
