"""Which scenes a batch runs: a folder of scene folders, or a YAML / CSV list.

Forms of ``MANIFEST`` (``voxnero batch MANIFEST ...``):

* a **folder of scene folders**: every non-hidden sub-folder is one scene, named after it
  (a folder that is itself a scene is a batch of one);
* a **YAML** file (``.yaml`` / ``.yml``), a list or a mapping with a ``scenes:`` list whose items
  are a path or a mapping::

      scenes:
        - scenes/sphere_gold                      # relative to the manifest's folder
        - path: /data/torus_ceramic
          name: torus                             # output sub-folder (default: folder name)
          overrides: [shape.iters=3000]           # or a mapping {shape.iters: 3000}

* a **CSV** file with a header naming a ``path`` column, optionally ``name`` and ``overrides``
  (``key=value`` items separated by spaces); lines starting with ``#`` are comments.

Per-scene overrides come after the command line's, so they win. Whether each path is a readable
scene is checked per scene (:func:`probe_scene`, then by the scene's task): one bad scene is an
error row in the results and does not stop the others.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from voxnero.errors import ConfigError, DataError

_OVERRIDE = re.compile(r"^[A-Za-z_][\w.]*=")


@dataclass
class SceneEntry:
    """One scene of a batch.

    Attributes:
        name: unique name, the scene's output sub-folder.
        path: scene folder (absolute).
        overrides: ``key=value`` items for this scene only (after the command line's).
    """

    name: str
    path: Path
    overrides: list[str] = field(default_factory=list)


def _safe_name(name: str) -> str:
    name = re.sub(r"[^\w.-]+", "_", name.strip()).strip("._")
    return name or "scene"


def _overrides(value: Any, where: str, manifest: Path) -> list[str]:
    if value is None or value == "":
        return []
    if isinstance(value, str):
        items = value.split()
    elif isinstance(value, dict):
        items = [f"{k}={yaml.safe_dump(v, default_flow_style=True).strip().removesuffix('...')}"
                 .strip() for k, v in value.items()]
    elif isinstance(value, list):
        items = [str(v) for v in value]
    else:
        raise ConfigError(f"{where}: overrides must be a list of key=value, a mapping or a string,"
                          f" got {value!r}", path=manifest)
    bad = [i for i in items if not _OVERRIDE.match(i)]
    if bad:
        raise ConfigError(f"{where}: override(s) {bad} are not of the form key=value",
                          path=manifest, fix="write e.g. shape.iters=3000")
    return items


def _unique(entries: list[SceneEntry]) -> list[SceneEntry]:
    seen: dict[str, int] = {}
    for e in entries:
        base = e.name
        n = seen.get(base, 0)
        seen[base] = n + 1
        if n:
            e.name = f"{base}-{n + 1}"
    return entries


def _from_folder(root: Path) -> list[SceneEntry]:
    from voxnero.data.detect import detect_format

    if detect_format(root) is not None:
        return [SceneEntry(_safe_name(root.name), root.resolve())]
    subs = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not subs:
        raise DataError("this folder holds no scene folders", path=root,
                        fix="pass a folder of scene folders, a scene folder, or a YAML/CSV list")
    return [SceneEntry(_safe_name(p.name), p.resolve()) for p in subs]


def _item(item: Any, where: str, manifest: Path) -> SceneEntry:
    if isinstance(item, str):
        item = {"path": item}
    if not isinstance(item, dict) or not item.get("path"):
        raise ConfigError(f"{where}: each scene must be a path or a mapping with 'path', got "
                          f"{item!r}", path=manifest)
    unknown = set(item) - {"path", "name", "overrides"}
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}", path=manifest,
                          fix="valid keys: path, name, overrides")
    path = Path(str(item["path"])).expanduser()
    if not path.is_absolute():
        path = manifest.parent / path
    name = _safe_name(str(item.get("name") or path.name))
    return SceneEntry(name, path.resolve(), _overrides(item.get("overrides"), where, manifest))


def _from_yaml(manifest: Path) -> list[SceneEntry]:
    try:
        data = yaml.safe_load(manifest.read_text())
    except yaml.YAMLError as e:
        raise DataError(f"invalid YAML ({e})", path=manifest, fix="repair the file") from None
    if isinstance(data, dict):
        if set(data) != {"scenes"}:
            raise ConfigError("a YAML manifest is a list of scenes or a mapping with only "
                              f"'scenes:', got keys {sorted(data)}", path=manifest)
        data = data["scenes"]
    if not isinstance(data, list) or not data:
        raise ConfigError("the manifest lists no scenes", path=manifest,
                          fix="write a list of scene paths (see 'voxnero batch --help')")
    return [_item(it, f"scene {i + 1}", manifest) for i, it in enumerate(data)]


def _from_csv(manifest: Path) -> list[SceneEntry]:
    lines = [ln for ln in manifest.read_text().splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise ConfigError("the CSV manifest is empty", path=manifest,
                          fix="write a header line path,name,overrides, then one scene folder "
                              "per line")
    reader = csv.DictReader(lines)
    cols = [c.strip() for c in (reader.fieldnames or [])]
    if "path" not in cols:
        raise ConfigError(f"the CSV header {cols} has no 'path' column", path=manifest,
                          fix="first line e.g.: path,name,overrides")
    out = []
    for i, row in enumerate(reader):
        row = {(k or "").strip(): (v or "").strip() for k, v in row.items() if k is not None}
        item = {k: row[k] for k in ("path", "name", "overrides") if row.get(k)}
        out.append(_item(item, f"row {i + 2}", manifest))
    if not out:
        raise ConfigError("the CSV manifest lists no scenes (a header only)", path=manifest,
                          fix="add one line per scene under the header, e.g. scenes/sphere,,")
    return out


def read_manifest(path: str | Path) -> list[SceneEntry]:
    """Read a manifest (folder of scene folders, scene folder, YAML or CSV list).

    Returns:
        The scenes in order, with unique names (``name-2``, ``name-3`` for repeats).

    Raises:
        DataError: the manifest is missing or unreadable.
        ConfigError: the manifest is readable but malformed (names the row and the fix).
    """
    p = Path(path).expanduser()
    if p.is_dir():
        return _unique(_from_folder(p))
    if not p.is_file():
        raise DataError("no such manifest folder or file", path=p,
                        fix="pass a folder of scene folders or a .yaml/.csv list of scenes")
    suffix = p.suffix.lower()
    if suffix in (".yaml", ".yml"):
        return _unique(_from_yaml(p))
    if suffix == ".csv":
        return _unique(_from_csv(p))
    raise DataError(f"unknown manifest type {suffix!r}", path=p,
                    fix="use a folder of scene folders, a .yaml/.yml or a .csv list")


def probe_scene(path: Path) -> str | None:
    """Cheap check (no images read) that ``path`` is a scene folder of a known format.

    Returns:
        None if it looks loadable, else a one-line error message naming the path and the fix.
    """
    from voxnero.data.detect import LOOKED_FOR, detect_format

    if not path.exists():
        return f"{path}: scene folder not found (fix: check the path in the manifest)"
    if not path.is_dir():
        return f"{path}: not a folder (fix: a scene is a folder of photos and poses)"
    try:
        fmt = detect_format(path)
    except Exception as e:  # noqa: BLE001 - a broken marker file is this scene's error only
        return f"{path}: unreadable scene ({type(e).__name__}: {e})"
    if fmt is None:
        return f"{path}: no known scene format, looked for {LOOKED_FOR}"
    if fmt == "blender":  # the pose files are small: parse them here rather than in a task
        import json

        for f in sorted(path.glob("transforms_*.json")):
            try:
                data = json.loads(f.read_text())
            except (OSError, ValueError) as e:
                return f"{f}: unreadable pose file ({e}) (fix: repair or replace the file)"
            if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
                return f"{f}: not a NeRF-synthetic pose file (no 'frames' list)"
    return None
