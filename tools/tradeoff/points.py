"""The points of a sweep: a preset plus ``key=value`` overrides (``--points``, YAML specs)."""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
DEFAULT_SPEC = REPO / "tools" / "tradeoff_configs" / "default.yaml"


@dataclass(frozen=True)
class Point:
    """One configuration of the sweep: a preset plus ``key=value`` overrides (full keys)."""

    name: str
    preset: str
    overrides: tuple[str, ...] = ()

    @property
    def is_preset(self) -> bool:
        """Whether the point is a preset as shipped (no overrides)."""
        return not self.overrides

    @property
    def config(self) -> str:
        """``"PRESET key=value ..."``: the point as one ``--points`` item."""
        return " ".join((self.preset, *self.overrides))

    def stages(self) -> set[str]:
        """Sections its overrides address (``{"shape"}``, ``{"material"}``, both or none)."""
        return {o.split("=", 1)[0].split(".", 1)[0] for o in self.overrides}

    def for_stage(self, stage: str) -> list[str]:
        """The overrides of one section (``"shape"`` or ``"material"``)."""
        return [o for o in self.overrides if o.split(".", 1)[0] == stage]


def _check_override(item: str, where: str) -> str:
    from voxnero.errors import ConfigError

    key = item.split("=", 1)[0]
    if "=" not in item or key.split(".", 1)[0] not in ("shape", "material") or "." not in key:
        raise ConfigError(f"{where}: override {item!r} needs a full key under shape. or material.",
                          fix="write e.g. shape.iters=800 or material.render.spp_cos=2")
    return item.strip()


def parse_point(item: str, base: str = "standard") -> Point:
    """One ``--points`` item: ``PRESET``, ``key=value`` or ``"PRESET key=value ..."``.

    A bare override (no preset word) applies to ``base``. The name is the item as written
    (normalised spacing), so equal items are the same point.
    """
    from voxnero.errors import ConfigError

    words = item.split()
    presets = [w for w in words if "=" not in w]
    if len(presets) > 1:
        raise ConfigError(f"--points item {item!r} names more than one preset {presets}",
                          fix="quote one point per item: \"standard shape.iters=800\"")
    ov = tuple(_check_override(w, "--points") for w in words if "=" in w)
    preset = presets[0] if presets else base
    return Point(" ".join(words), preset, ov)


def load_spec(path: str | Path) -> list[Point]:
    """Points of a YAML sweep spec: ``points: [{name, preset, overrides: [k=v, ...]}]``."""
    import yaml

    from voxnero.errors import ConfigError

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise ConfigError(f"cannot read the sweep spec: {e}", path=path) from None
    items = doc.get("points") if isinstance(doc, dict) else None
    if not isinstance(items, list) or not items:
        raise ConfigError("a sweep spec needs a non-empty list 'points'", path=path,
                          fix="points: [{name: fast, preset: standard, "
                              "overrides: [shape.iters=800]}]")
    out = []
    for i, it in enumerate(items):
        if not isinstance(it, dict) or "preset" not in it or set(it) - {"name", "preset",
                                                                          "overrides"}:
            raise ConfigError(f"points[{i}] must be a mapping with preset (and optional name, "
                              f"overrides), got {it!r}", path=path)
        ov = tuple(_check_override(str(o), f"{path} points[{i}]") for o in it.get("overrides")
                   or [])
        name = str(it.get("name") or " ".join((it["preset"], *ov)))
        out.append(Point(name, str(it["preset"]), ov))
    return out


def resolve_points(items: Sequence[str] | None, base: str = "standard") -> list[Point]:
    """``--points`` items (presets, ``key=value``, quoted points, YAML specs) to points.

    Raises:
        ConfigError: two different points share a name.
    """
    from voxnero.errors import ConfigError

    points: list[Point] = []
    for item in items or [str(DEFAULT_SPEC)]:
        if item.endswith((".yaml", ".yml")) and "=" not in item:
            points += load_spec(item)
        else:
            points.append(parse_point(item, base))
    seen: dict[str, Point] = {}
    uniq = []
    for p in points:
        if p.name in seen:
            if seen[p.name] != p:
                raise ConfigError(f"two points are named {p.name!r}", fix="rename one of them")
            continue
        seen[p.name] = p
        uniq.append(p)
    return uniq


def points_for_stage(points: Iterable[Point], stage: str) -> list[Point]:
    """Points meaningful for ``stage``: presets, and points with overrides of a timed stage.

    A stage-2-only knob is dropped from a stage-1 sweep (it would repeat its preset), and a
    stage-1-only knob from a stage-2 sweep (stage 1 is not timed there).
    """
    timed = {"shape": {"shape"}, "material": {"material"}, "both": {"shape", "material"}}[stage]
    return [p for p in points if p.is_preset or p.stages() & timed]
