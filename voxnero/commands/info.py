"""``voxnero info``: describe a scene folder (or a run folder) without changing anything.

For a scene: detected format, splits with #views and image size, intrinsics, the chosen
normalisation, up axis, background handling and whether evaluation masks/depth exist. For a
run folder (one holding ``config.yaml``): its resolved config sections and files. With
``--out DIR`` the same facts are written to ``DIR/info.json``.

Options of the scene loader are given as overrides: ``splits=[train,test]``, ``white_bg=true``,
``radius=1.5``, ``center=[0,0,0]``, ``bbox=[-1,-1,-1,1,1,1]``, ``images_dir=PATH`` (COLMAP).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import yaml

from voxnero.cli import add_common
from voxnero.config import Range, from_dict, parse_overrides, positive
from voxnero.errors import DataError

NAME = "info"
HELP = "describe a scene (format, splits, cameras, normalisation) or a run folder"


@dataclass
class InfoOptions:
    """Scene-loading options accepted as ``key=value`` by ``voxnero info``."""

    RANGES: ClassVar[dict[str, Range]] = {"radius": positive(), "center": Range(),
                                          "bbox": Range()}

    splits: list[str] | None = None
    white_bg: bool = False
    radius: float | None = None
    center: list[float] | None = None
    bbox: list[float] | None = None
    images_dir: str | None = None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_common(parser, "scene folder (Blender, NeRO or COLMAP) or run folder",
               out_required=False)


def scene_info(scene) -> dict[str, Any]:
    """JSON-friendly facts about a loaded ``Scene``."""
    splits = {}
    for s in scene.splits.values():
        K = s.cameras.K
        splits[s.name] = {
            "views": s.n, "width": s.width, "height": s.height,
            "K_first": [[round(float(v), 6) for v in row] for row in K[0].tolist()],
            "intrinsics_shared": bool((K == K[:1]).all()),
            "alpha": s.alpha is not None, "masks": s.masks is not None,
            "depth": s.depth is not None,
        }
    return {"kind": "scene", "root": str(scene.root), "format": scene.format, "splits": splits,
            "normalisation": scene.meta.get("normalisation", scene.norm.to_dict()),
            "up": [float(v) for v in scene.up], "background": scene.background,
            "meta": {k: v for k, v in scene.meta.items() if k != "normalisation"}}


def run_info(folder: Path) -> dict[str, Any]:
    """Facts about a run folder: config sections and the files it holds."""
    cfg_path = folder / "config.yaml"
    try:
        cfg = yaml.safe_load(cfg_path.read_text()) or {}
    except yaml.YAMLError as e:
        raise DataError(f"invalid YAML ({e})", path=cfg_path, fix="repair the file") from None
    files = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file())
    return {"kind": "run", "root": str(folder),
            "config_sections": sorted(cfg) if isinstance(cfg, dict) else [],
            "n_files": len(files), "files": files[:200]}


def run(args: argparse.Namespace) -> int:
    from voxnero.data.detect import available_splits, detect_format, load_scene

    opts = from_dict(InfoOptions, parse_overrides(args.overrides, None))
    target = Path(args.target)
    if target.is_dir() and detect_format(target) is None and (target / "config.yaml").is_file():
        info = run_info(target)
        print(f"run         {info['root']}")
        print(f"config      sections {info['config_sections']}")
        print(f"files       {info['n_files']}")
        for f in info["files"][:30]:
            print(f"  {f}")
    else:
        splits = opts.splits or available_splits(target) or ["train"]
        scene = load_scene(target, splits=tuple(splits), white_bg=opts.white_bg,
                           radius=opts.radius, center=opts.center, bbox=opts.bbox,
                           eval_extras=True, images_dir=opts.images_dir)
        info = scene_info(scene)
        print(scene.summary())
        extras = [f"{n}: masks={d['masks']} depth={d['depth']} alpha={d['alpha']}"
                  for n, d in info["splits"].items()]
        print("eval extras " + "; ".join(extras))
    if args.out:
        from voxnero.safety.folder import RunFolder, atomic_write_text

        with RunFolder(args.out, "info") as run:
            atomic_write_text(run.path / "info.json", json.dumps(info, indent=1, default=str))
        print(f"wrote {run.path / 'info.json'}")
    return 0
