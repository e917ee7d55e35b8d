"""Configuration: a dataclass per component, YAML presets in ``configs/``, ``key=value`` overrides.

A preset file (``configs/<name>.yaml``) is a mapping of sections, one per command stage
(``shape:``, ``material:``, ``synth:`` ...). Each section is parsed into that stage's dataclass
with :func:`from_dict`, which rejects unknown keys. Overrides are dotted paths into the preset
(``shape.iters=3000``); inside a single-stage command the section may be left out
(``iters=3000`` means ``shape.iters=3000`` for ``voxnero shape``). Values are parsed as YAML
scalars (``1e-3``, ``true``, ``[64, 128]``). The resolved config is written beside every output
with :func:`save_resolved` so that a run can be repeated exactly.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

from voxnero.errors import ConfigError

Switch = typing.Literal["auto", "on", "off"] | bool
"""A model switch of either stage; YAML reads on/off as true/false, which mean the same."""

T = TypeVar("T")

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"
"""Where the named presets live (the repository's ``configs/``)."""


def available_presets() -> list[str]:
    """Names of the presets found in :data:`CONFIG_DIR`."""
    return sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))


def load_preset(name_or_path: str) -> dict[str, Any]:
    """Load a preset by name (``configs/<name>.yaml``) or by path to a YAML file.

    Returns:
        The raw mapping of sections.
    """
    path = Path(name_or_path)
    if not path.suffix:
        path = CONFIG_DIR / f"{name_or_path}.yaml"
    if not path.is_file():
        raise ConfigError(f"preset {name_or_path!r} not found",
                          fix=f"use one of {available_presets()} or a path to a YAML file")
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as e:
        raise ConfigError(f"invalid YAML: {e}", path=path) from None
    if not isinstance(data, dict):
        raise ConfigError("a preset must be a mapping of sections", path=path)
    return data


def parse_overrides(items: list[str], default_section: str | None,
                    sections: typing.Iterable[str] = ()) -> dict[str, Any]:
    """Turn ``["a.b=1", "c=[1,2]"]`` into a nested dict.

    Args:
        items: ``key=value`` strings; values are YAML scalars or flow sequences.
        default_section: section prepended to keys whose first part is not a known section.
        sections: the known top-level section names.
    """
    sections = set(sections)
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise ConfigError(f"override {item!r} is not of the form key=value",
                              fix="write e.g. iters=2000 or shape.grid.res=96")
        key, raw = item.split("=", 1)
        key = key.strip()
        try:
            value = yaml.safe_load(raw) if raw.strip() else ""
        except yaml.YAMLError:
            value = raw
        if isinstance(value, str):  # PyYAML (YAML 1.1) reads "1e-3" as a string
            try:
                value = float(value)
            except ValueError:
                pass
        parts = key.split(".")
        if default_section and parts[0] not in sections:
            parts = [default_section] + parts
        node = out
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"override {item!r} conflicts with another override")
        node[parts[-1]] = value
    return out


def deep_merge(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """Recursively merge ``update`` into a copy of ``base``."""
    out = dict(base)
    for k, v in update.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = v
    return out


def _coerce(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where} must be a mapping, got {value!r}")
        return from_dict(tp, value, where)
    if origin is typing.Union or origin is types.UnionType:
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(a, value, where)
            except ConfigError as e:
                errors.append(str(e))
        raise ConfigError(f"{where}={value!r} does not fit {tp}")
    if origin in (list, tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        inner = args[0] if args else Any
        return type(value)(_coerce(inner, v, f"{where}[]") for v in value) if origin is list \
            else tuple(_coerce(inner, v, f"{where}[]") for v in value)
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(f"{where}={value!r} must be one of {list(args)}")
        return value
    if tp is Any:
        return value
    if tp is bool:
        if isinstance(value, bool):
            return value
        raise ConfigError(f"{where} must be true or false, got {value!r}")
    if tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str):  # "1e-3" in a YAML file is a string for PyYAML
            try:
                return float(value)
            except ValueError:
                pass
        raise ConfigError(f"{where} must be a number, got {value!r}")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ConfigError(f"{where} must be an integer, got {value!r}")
    if tp is str:
        if isinstance(value, (str, int, float)) and not isinstance(value, bool):
            return str(value)
        raise ConfigError(f"{where} must be a string, got {value!r}")
    return value


def from_dict(cls: type[T], data: dict[str, Any], where: str = "") -> T:
    """Build dataclass ``cls`` from ``data``, checking names and types.

    Unknown keys raise :class:`ConfigError` listing the valid ones.
    """
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        keys = sorted(f"{where}.{k}" if where else k for k in unknown)
        raise ConfigError(f"unknown config key(s) {keys}",
                          fix=f"valid keys{' under ' + where if where else ''}: {sorted(names)}")
    kwargs = {}
    for k, v in data.items():
        kwargs[k] = _coerce(hints[k], v, f"{where}.{k}" if where else k)
    obj = cls(**kwargs)
    validate = getattr(obj, "validate", None)
    if callable(validate):
        validate()
    return obj


def to_dict(obj: Any) -> Any:
    """Dataclass (possibly nested) to plain dicts/lists for YAML/JSON."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, Path):
        return str(obj)
    return obj


def resolve(cls: type[T], section: str, preset: str, overrides: list[str],
            extra_sections: typing.Iterable[str] = ()) -> T:
    """Load ``preset``, apply ``overrides`` and build the ``section`` dataclass.

    Args:
        cls: dataclass of the section (e.g. ``ShapeConfig``).
        section: name of the section in the preset file (e.g. ``"shape"``).
        preset: preset name or YAML path.
        overrides: ``key=value`` strings (keys relative to the preset root or to ``section``).
        extra_sections: other section names that overrides may address.
    """
    raw = load_preset(preset)
    known = set(raw) | {section} | set(extra_sections)
    ov = parse_overrides(overrides, section, known)
    merged = deep_merge(raw, ov)
    return from_dict(cls, merged.get(section, {}) or {}, section)


def save_resolved(out_dir: str | Path, sections: dict[str, Any], meta: dict[str, Any] | None = None
                  ) -> Path:
    """Write ``config.yaml`` (the resolved config of every section given) into ``out_dir``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {k: to_dict(v) for k, v in sections.items()}
    if meta:
        doc["_meta"] = meta
    path = out_dir / "config.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path
