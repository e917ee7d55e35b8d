"""Tests of voxnero/config.py: presets, overrides, type checks, resolved config."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.fixtures.config_settings import (
    is_list,
    numeric_fields,
    out_of_range,
    resolved_presets,
    sections,
)
from voxnero.config import (
    Range,
    available_presets,
    check_numbers,
    from_dict,
    load_preset,
    parse_overrides,
    resolve,
    save_resolved,
    to_dict,
)
from voxnero.errors import ConfigError


@dataclass
class Inner:
    res: int = 32
    lr: float = 1e-2


@dataclass
class Outer:
    iters: int = 100
    name: str = "x"
    flag: bool = False
    levels: list[int] = field(default_factory=lambda: [1, 2])
    inner: Inner = field(default_factory=Inner)
    opt: float | None = None


def test_from_dict_types_and_nesting():
    c = from_dict(Outer, {"iters": 5.0, "inner": {"lr": 3}, "levels": [4], "opt": 2})
    assert c.iters == 5 and isinstance(c.iters, int)
    assert c.inner.lr == 3.0 and isinstance(c.inner.lr, float) and c.inner.res == 32
    assert c.levels == [4] and c.opt == 2.0


@pytest.mark.parametrize("bad, msg", [
    ({"iterz": 1}, "unknown config key"),
    ({"iters": "many"}, "must be an integer"),
    ({"iters": 1.5}, "must be an integer"),
    ({"flag": 1}, "true or false"),
    ({"inner": {"res": [1]}}, "inner.res"),
    ({"inner": 3}, "must be a mapping"),
])
def test_from_dict_rejects(bad, msg):
    with pytest.raises(ConfigError, match=msg):
        from_dict(Outer, bad)


def test_overrides_default_section_and_yaml_values():
    ov = parse_overrides(["iters=7", "shape.inner.lr=1e-3", "material.x=[1, 2]", "flag=true"],
                         "shape", {"shape", "material"})
    assert ov == {"shape": {"iters": 7, "inner": {"lr": 1e-3}, "flag": True},
                  "material": {"x": [1, 2]}}
    with pytest.raises(ConfigError, match="key=value"):
        parse_overrides(["oops"], "shape", {"shape"})


def test_resolve_from_file_and_save(tmp_path):
    p = tmp_path / "p.yaml"
    p.write_text(yaml.safe_dump({"shape": {"iters": 3, "inner": {"res": 8}}}))
    c = resolve(Outer, "shape", str(p), ["inner.lr=0.5"])
    assert (c.iters, c.inner.res, c.inner.lr) == (3, 8, 0.5)
    out = save_resolved(tmp_path / "run", {"shape": c})
    back = yaml.safe_load(out.read_text())["shape"]
    assert back == to_dict(c)
    assert from_dict(Outer, back) == c  # the saved config reproduces the run's config


def test_base_preset_is_merged_under_the_file(tmp_path):
    """``base: NAME`` loads NAME first; the file's keys win, the base's others stay, nested."""
    (tmp_path / "b.yaml").write_text(yaml.safe_dump(
        {"shape": {"iters": 3, "inner": {"res": 8, "lr": 0.25}}, "material": {"x": 1}}))
    (tmp_path / "c.yaml").write_text(yaml.safe_dump({"base": "b.yaml", "shape": {"inner": {"res": 4}}}))
    raw = load_preset(str(tmp_path / "c.yaml"))
    assert raw == {"shape": {"iters": 3, "inner": {"res": 4, "lr": 0.25}}, "material": {"x": 1}}
    c = resolve(Outer, "shape", str(tmp_path / "c.yaml"), ["iters=5"])
    assert (c.iters, c.inner.res, c.inner.lr) == (5, 4, 0.25)


def test_quality_stage_1_is_standard():
    """``quality`` names ``standard`` as its base and changes no stage-1 setting (finding 59)."""
    from voxnero.material.config import MaterialConfig
    from voxnero.shape.config import ShapeConfig

    assert resolve(ShapeConfig, "shape", "quality", []) == resolve(ShapeConfig, "shape", "standard", [])
    q, s = (resolve(MaterialConfig, "material", p, []) for p in ("quality", "standard"))
    assert q.texture_size > s.texture_size


@pytest.mark.parametrize("files, words", [
    ({"a.yaml": {"base": "b.yaml"}, "b.yaml": {"base": "a.yaml"}}, "in a loop"),
    ({"a.yaml": {"base": "a.yaml"}}, "in a loop"),
    ({"a.yaml": {"base": 3}}, "must name a preset"),
    ({"a.yaml": {"base": "no_such_preset"}}, "not found")])
def test_bad_base_is_refused_with_the_file(tmp_path, files, words):
    for name, doc in files.items():
        (tmp_path / name).write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match=words):
        load_preset(str(tmp_path / "a.yaml"))


def test_missing_preset_lists_available():
    with pytest.raises(ConfigError, match="not found"):
        resolve(Outer, "shape", "no_such_preset", [])


# --------------------------------------------------------------------------------------------
# numbers: finite and inside each class's RANGES table (check_numbers)
# --------------------------------------------------------------------------------------------

NUMERIC = numeric_fields()


def test_every_numeric_setting_has_a_range_and_every_range_a_field():
    missing = [k for k, cls, f in NUMERIC if f.name not in getattr(cls, "RANGES", {})]
    assert not missing, f"numeric settings without a RANGES entry: {missing}"
    for _, cls, _ in NUMERIC:
        assert set(cls.RANGES) <= {f.name for f in dataclasses.fields(cls)}, cls
    assert len(NUMERIC) > 120


def test_defaults_and_every_preset_are_in_range():
    seen = {cls for _, cls, _ in NUMERIC}
    for cls in seen:
        check_numbers(cls())
    for preset in available_presets():
        for name, cls in sections().items():
            if name != "info":
                resolve(cls, name, preset, [])


def test_presets_resolve_as_recorded():
    """The presets, raw and resolved, equal the record taken before they moved into
    ``voxnero/configs/`` and were rewritten as block-style YAML (issue 24). A deliberate change
    of a preset or a default rewrites the record: ``json.dump(resolved_presets(), f, indent=1,
    sort_keys=True)`` into ``tests/fixtures/presets_resolved.json``."""
    record = json.loads((Path(__file__).parent / "fixtures" / "presets_resolved.json").read_text())
    assert resolved_presets() == record


@dataclass
class Ranged:
    RANGES: ClassVar[dict[str, Range]] = {"lr": Range(0.0, 1.0), "n": Range(1, None),
                                          "views": Range(1, None, also=(-1,)),
                                          "eps": Range(0.0, 1.0, lo_open=True)}
    lr: float = 0.1
    n: int = 4
    views: int = -1
    eps: float = 1e-3
    levels: list[float] = field(default_factory=lambda: [0.5])
    opt: float | None = None


@pytest.mark.parametrize("key, value, words", [
    ("lr", math.nan, "lr=nan is not a finite number"), ("lr", 2.0, "lr=2.0 is out of range"),
    ("n", 0, "n=0 is out of range (must be >= 1)"), ("views", 0, "must be >= 1 or -1"),
    ("eps", 0.0, "must be in (0, 1]"), ("levels", [0.5, math.inf], "levels=[0.5, inf]"),
    ("opt", math.nan, "opt=nan")])
def test_check_numbers_names_key_value_and_fix(key, value, words):
    with pytest.raises(ConfigError) as e:
        from_dict(Ranged, {key: value}, "sec")
    assert f"sec.{words}" in str(e.value) or words in str(e.value), str(e.value)
    assert e.value.fix and ("the default" in e.value.fix or "leave" in e.value.fix)


def test_check_numbers_accepts_boundaries_and_special_values():
    from_dict(Ranged, {"lr": 0.0, "views": -1, "eps": 1.0, "n": 10 ** 6, "opt": 3.0})
    from_dict(Ranged, {"lr": 1.0, "views": 7})


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(NUMERIC), st.data())
def test_any_non_finite_or_out_of_range_setting_is_refused(entry, data):
    """Every numeric key of every command: NaN, ±Inf and values just past its bounds raise a
    ConfigError naming the dotted key, whatever the other settings are."""
    key, cls, f = entry
    r = cls.RANGES[f.name]
    value = data.draw(st.sampled_from(out_of_range(r)))
    section, *rest = key.split(".")
    name = ".".join(rest)
    override = f"{name}=[{value!r}]" if is_list(cls, f.name) else f"{name}={value!r}"
    cfg_cls = sections()[section]
    with pytest.raises(ConfigError) as e:
        if section == "info":
            from_dict(cfg_cls, parse_overrides([override], None))
        else:
            resolve(cfg_cls, section, "tiny", [override])
    assert (name if section == "info" else key) in str(e.value), str(e.value)
    assert "is not a finite number" in str(e.value) or "out of range" in str(e.value) or \
        "must be an integer" in str(e.value), str(e.value)
