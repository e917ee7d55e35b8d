"""Configuration: a dataclass per component, YAML presets, ``key=value`` overrides.

A preset file (``voxnero/configs/<name>.yaml``, package data) is a mapping of sections, one
per command stage (``shape:``, ``material:``, ``synth:`` ...), optionally over another preset it
names as ``base:`` (:func:`load_preset`). Each section is parsed into that
stage's dataclass with :func:`from_dict`, which rejects unknown keys and checks every number
(:func:`check_numbers`: finite, and inside the class's ``RANGES`` table) before the class's own
``validate()``; a command resolves its config before it reads any data, so a bad setting stops
it before any work. Overrides are dotted paths into the preset (``shape.iters=3000``); inside
a single-stage command the section may be left out (``iters=3000`` means ``shape.iters=3000``
for ``voxnero shape``). Values are parsed as YAML scalars (``1e-3``, ``true``, ``[64, 128]``).
The resolved config is written beside every output with :func:`save_resolved` so that a run can
be repeated exactly.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

from voxnero.errors import ConfigError

Switch = typing.Literal["auto", "on", "off"] | bool
"""A model switch of either stage; YAML reads on/off as true/false, which mean the same."""

T = TypeVar("T")

CONFIG_DIR = Path(__file__).resolve().parent / "configs"
"""Where the named presets live: ``voxnero/configs/``, package data (setup.cfg), so that an
installed wheel finds them; the repository's top-level ``configs`` links there."""


def available_presets() -> list[str]:
    """Names of the presets found in :data:`CONFIG_DIR`."""
    return sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))


def load_preset(name_or_path: str, _seen: tuple[str, ...] = ()) -> dict[str, Any]:
    """Load a preset by name (``voxnero/configs/<name>.yaml``) or by path to a YAML file.

    A preset may start from another: a top-level ``base: NAME`` (a preset name or path) loads
    that one first and merges this file's sections over it (:func:`deep_merge`), so a preset
    lists only what it changes from its base and follows the base when the base is retuned.

    Returns:
        The raw mapping of sections, bases merged (``base`` itself removed).
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
    base = data.pop("base", None)
    if base is None:
        return data
    if not isinstance(base, str) or not base:
        raise ConfigError(f"'base' must name a preset, not {base!r}", path=path,
                          fix=f"write e.g. base: standard (one of {available_presets()})")
    key = str(path.resolve())
    if key in _seen:
        raise ConfigError(f"presets name each other as base in a loop: {' -> '.join(_seen + (key,))}",
                          path=path, fix="remove one of the 'base' lines")
    # a bare name is a shipped preset; a path is read relative to this file (an absolute one as is)
    parent = base if not Path(base).suffix and Path(base).name == base else str(path.parent / base)
    return deep_merge(load_preset(parent, _seen + (key,)), data)


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
        errors: list[ConfigError] = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(a, value, where)
            except ConfigError as e:
                errors.append(e)
        if len(errors) == 1:  # X | None: X's own message says more
            raise errors[0]
        raise ConfigError(f"{where}={value!r} does not fit {tp}",
                          fix=next((e.fix for e in errors if e.fix), None))
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
        raise ConfigError(f"{where} must be a number, got {value!r}",
                          fix=f"write e.g. {where}=0.5 or {where}=1e-3")
    if tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        if isinstance(value, float) and value.is_integer():
            return int(value)
        raise ConfigError(f"{where} must be an integer, got {value!r}",
                          fix=f"write a whole number, e.g. {where}=100")
    if tp is str:
        if isinstance(value, (str, int, float)) and not isinstance(value, bool):
            return str(value)
        raise ConfigError(f"{where} must be a string, got {value!r}")
    return value


@dataclasses.dataclass(frozen=True)
class Range:
    """The values a numeric config key accepts: ``lo <= v <= hi`` (``<`` where open), or one
    of the special values ``also`` (e.g. -1 = "all").

    Config dataclasses list theirs in a class attribute ``RANGES: ClassVar[dict[str, Range]]``
    (field name -> Range; a list-valued field applies it to every element), checked by
    :func:`check_numbers`.
    """

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    also: tuple[float, ...] = ()

    def __contains__(self, v: float) -> bool:
        if v in self.also:
            return True
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return not (self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi))

    def __str__(self) -> str:
        lo, hi = _num(self.lo), _num(self.hi)
        if self.lo is not None and self.hi is not None:
            txt = f"in {'(' if self.lo_open else '['}{lo}, {hi}{')' if self.hi_open else ']'}"
        elif self.lo is not None:
            txt = f"{'>' if self.lo_open else '>='} {lo}"
        elif self.hi is not None:
            txt = f"{'<' if self.hi_open else '<='} {hi}"
        else:
            txt = ""
        return txt + "".join(f" or {_num(a)}" for a in self.also)


def _num(v: float | None) -> str:
    """``1e+09`` -> ``1e9``: bounds as a user would type them."""
    return f"{v:g}".replace("e+0", "e").replace("e+", "e") if v is not None else ""


def at_least(lo: float, hi: float | None = None, also: tuple[float, ...] = ()) -> Range:
    """``lo <= v`` (``<= hi`` if given), or one of ``also``."""
    return Range(lo, hi, also=also)


def positive(hi: float | None = None) -> Range:
    """``0 < v`` (``<= hi`` if given)."""
    return Range(0.0, hi, lo_open=True)


FRACTION = Range(0.0, 1.0)
"""A fraction of ``iters`` (or any share) in [0, 1]."""
WEIGHT = Range(0.0, 1e6)
"""A loss weight or regulariser strength: >= 0 (0 = off); 1e6 as a bound on typos."""
LEARNING_RATE = Range(0.0, 1.0)
"""An Adam learning rate: Adam moves each parameter by about lr per step, and every parameter
here lives in units of order 1, so lr > 1 only throws them about (0 freezes a group)."""
SEED = Range(0.0, 2.0 ** 32 - 1)
"""A random seed (numpy and torch both take [0, 2³² − 1])."""
THREADS = Range(0.0, 4096.0)
"""torch CPU threads (0 = torch's default)."""
BIG_COUNT = 1e9
"""Upper bound of counts such as rays per batch or cached pixels: a larger value is a typo
(it could not fit in memory)."""


def check_numbers(obj: Any, where: str = "") -> None:
    """Refuse a non-finite float, or a number outside its ``RANGES`` entry, in any field of
    the dataclass ``obj`` (list elements included).

    Not recursive: :func:`from_dict` calls it for every nested section it builds (defaults of
    sections a preset leaves out are in range by construction; tests check it).

    Args:
        obj: a config dataclass instance.
        where: its dotted section (``"shape.optim"``), for messages.

    Raises:
        ConfigError: naming the key, the value, the allowed range and the default as the fix.
    """
    ranges: dict[str, Range] = getattr(type(obj), "RANGES", {})
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        items = value if isinstance(value, (list, tuple)) else [value]
        for v in items:
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                continue
            r = ranges.get(f.name)
            finite = not (isinstance(v, float) and not math.isfinite(v))
            if finite and (r is None or v in r):
                continue
            key = f"{where}.{f.name}" if where else f.name
            bounds = f" {r}" if r is not None and str(r) else ""
            what = "is not a finite number" if not finite else f"is out of range (must be{bounds})"
            default = _default(f)
            example = (f"leave {key} out" if default is None
                       else f"e.g. {key}={default!r} (the default)")
            raise ConfigError(f"{key}={value!r} {what}",
                              fix=f"give a finite number{bounds}; {example}")


def _default(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return to_dict(f.default_factory())
    return None


def from_dict(cls: type[T], data: dict[str, Any], where: str = "") -> T:
    """Build dataclass ``cls`` from ``data``, checking names, types and numbers.

    Unknown keys raise :class:`ConfigError` listing the valid ones; then every number is checked
    (:func:`check_numbers`) and the class's own ``validate()`` (cross-field rules) runs.
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
    check_numbers(obj, where)
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
    """Write ``config.yaml`` (the resolved config of every section given) into ``out_dir``,
    atomically (a command writes it into its run folder's staging folder: it appears only when
    the run succeeded)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    doc = {k: to_dict(v) for k, v in sections.items()}
    if meta:
        doc["_meta"] = meta
    from voxnero.safety.folder import atomic_write_text

    return atomic_write_text(out_dir / "config.yaml", yaml.safe_dump(doc, sort_keys=False))


def read_meta(run: str | Path) -> dict[str, Any]:
    """The ``_meta`` section of a run folder's ``config.yaml`` (what :func:`save_resolved` wrote
    with the resolved config: the ``scene``, the stage-1 ``mesh``, ...): the one reader of a run's
    metadata.

    Args:
        run: the run folder.

    Returns:
        The section as a dict; empty when the folder has no ``config.yaml``, the file is not
        valid YAML or it has no ``_meta``.
    """
    cfg = Path(run) / "config.yaml"
    if not cfg.is_file():
        return {}
    try:
        doc = yaml.safe_load(cfg.read_text()) or {}
    except yaml.YAMLError:
        return {}
    meta = doc.get("_meta") if isinstance(doc, dict) else None
    return meta if isinstance(meta, dict) else {}
