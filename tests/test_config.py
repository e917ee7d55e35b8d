"""Tests of voxnero/config.py: presets, overrides, type checks, resolved config."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
import yaml

from voxnero.config import from_dict, parse_overrides, resolve, save_resolved, to_dict
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


def test_missing_preset_lists_available():
    with pytest.raises(ConfigError, match="not found"):
        resolve(Outer, "shape", "no_such_preset", [])
