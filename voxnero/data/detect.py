"""``load_scene``: detect a scene folder's format and load it.

Formats are tried in this order (the first whose marker files exist wins):

1. ``blender``: ``transforms_*.json`` in the folder (NeRF-synthetic / instant-ngp style);
2. ``nero``: ``*-camera.pkl`` files (NeRO GlossySynthetic);
3. ``idr``: ``cameras_sphere.npz`` (or ``cameras.npz``) + ``image/`` (NeuS/IDR, e.g. DTU);
4. ``colmap``: ``sparse/0/``, ``sparse/`` or the folder itself holding ``cameras`` and
   ``images`` ``.bin``/``.txt``.

A path to a file inside the scene (e.g. ``transforms_train.json``) means its folder.
"""

from __future__ import annotations

from pathlib import Path

from voxnero.data.blender import is_blender, load_blender
from voxnero.data.colmap import is_colmap, load_colmap
from voxnero.data.idr import is_idr, load_idr, split_names
from voxnero.data.nero import is_nero, load_nero
from voxnero.data.scene import Scene
from voxnero.errors import DataError

LOOKED_FOR = ("transforms_train.json (Blender/NeRF-synthetic), <k>-camera.pkl (NeRO), "
              "cameras_sphere.npz + image/ (NeuS/IDR), "
              "sparse/0/cameras.{bin,txt} + images.{bin,txt} (COLMAP)")
"""What :func:`detect_format` looks for, for error messages."""


def detect_format(path: str | Path) -> str | None:
    """``"blender"``, ``"nero"``, ``"idr"``, ``"colmap"`` or None for a scene folder."""
    root = Path(path)
    if is_blender(root):
        return "blender"
    if is_nero(root):
        return "nero"
    if is_idr(root):
        return "idr"
    if is_colmap(root):
        return "colmap"
    return None


def available_splits(path: str | Path) -> list[str]:
    """Names of the splits a scene folder offers (without loading images).

    Blender: one per ``transforms_<split>.json``; IDR: train/test/all (index % 8) or the
    keys of ``split.json``; NeRO / COLMAP: the keys of ``split.json``, or
    ``["train"]`` without one.
    """
    import json

    root = Path(path)
    if root.is_file():
        root = root.parent
    fmt = detect_format(root)
    if fmt == "blender":
        names = sorted(p.stem[len("transforms_"):] for p in root.glob("transforms_*.json"))
        return sorted(names, key=lambda n: (n != "train", n != "test", n))
    if fmt is None:
        return []
    if fmt == "idr":
        return split_names(root)
    sfile = root / "split.json"
    if sfile.is_file():
        try:
            data = json.loads(sfile.read_text())
        except json.JSONDecodeError as e:
            raise DataError(f"invalid JSON ({e})", path=sfile, fix="repair the file") from None
        if isinstance(data, dict):
            return sorted(data, key=lambda n: (n != "train", n != "test", n))
    return ["train"]


def load_scene(path: str | Path, splits=("train",), white_bg: bool = False,
               radius: float | None = None, center=None, bbox=None,
               eval_extras: bool = False, images_dir: str | Path | None = None,
               masks_as_alpha: bool = False) -> Scene:
    """Load a scene folder of any supported format into the unit frame.

    Args:
        path: scene folder (or a file inside it).
        splits: split names to load (``"train"``, ``"test"``, ...).
        white_bg: composite images that have alpha on white instead of black.
        radius: input-frame radius of the region of interest (overrides the default
            normalisation's scale); see :mod:`voxnero.data.scene`.
        center: ``(3,)`` input-frame centre of the region of interest.
        bbox: ``(xmin, ymin, zmin, xmax, ymax, zmax)`` region of interest (wins over radius and
            center).
        eval_extras: also load evaluation-only data: ``<split>_mask/`` coverage masks and
            (Blender dev scenes) ``gt/<split>_depth/`` z-depth, NeRO ``<k>-depth.png``.
        images_dir: COLMAP only: folder of the images if not ``<scene>/images``.
        masks_as_alpha: IDR only: train with the capture's masks as alpha
            (``shape.use_masks=true``).

    Returns:
        The ``Scene``; ``scene.meta["normalisation"]`` records how the normalisation was chosen.

    Raises:
        DataError: missing folder, unknown format, or bad data (the message names the file).
    """
    root = Path(path)
    if root.is_file():
        root = root.parent
    if not root.is_dir():
        raise DataError("scene folder not found", path=root, fix="check the path")
    if isinstance(splits, str):
        splits = (splits,)
    kw = dict(splits=tuple(splits), white_bg=white_bg, radius=radius, center=center, bbox=bbox,
              eval_extras=eval_extras)
    fmt = detect_format(root)
    if masks_as_alpha and fmt != "idr":
        raise DataError(f"use_masks=true is supported for NeuS/IDR captures only (this is "
                        f"{fmt})", path=root, fix="drop use_masks=true")
    if fmt == "idr":
        return load_idr(root, masks_as_alpha=masks_as_alpha, **kw)
    if fmt == "blender":
        return load_blender(root, **kw)
    if fmt == "nero":
        return load_nero(root, **kw)
    if fmt == "colmap":
        return load_colmap(root, images_dir=images_dir, **kw)
    raise DataError(f"no known format: looked for {LOOKED_FOR}", path=root,
                    fix="point to a scene folder in one of these formats")
