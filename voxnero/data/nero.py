"""Loader of NeRO "GlossySynthetic" scenes.

Format (one folder per object): ``{k}.png`` (k = 0, 1, 2 ...), ``{k}-camera.pkl`` holding the
pickled list ``[pose, K]`` with ``pose`` a 3x4 world-to-camera OpenCV matrix and ``K`` 3x3
intrinsics in pixels, and optionally ``{k}-depth.png`` (16-bit, ``depth = v / 65535 * 15``,
z-depth; ``depth >= 14.5`` means background, stored as 0). Images are 8-bit sRGB; an alpha
channel, if any, is composited like the Blender loader does.

Splits: NeRO ships no split list, so **every view is in "train"** unless the folder holds a
``split.json`` mapping split names to lists of view ids, e.g. ``{"train": [0, 1, ...],
"test": [5, 17]}``. Asking for any other split without such a file is a DataError.

The pickles are read with a restricted unpickler that only builds numpy arrays and plain Python
containers, so a hostile file cannot run code. The world is Blender's (NeRO rendered these
scenes in Blender), so up is **+Z**. The principal point is used as stored (pixel centre +0.5,
the Blender convention).
"""

from __future__ import annotations

import json
import pickle
import re
from pathlib import Path

import numpy as np

from voxnero.cameras.cameras import w2c_to_c2w
from voxnero.data.scene import (
    Scene,
    check_camera,
    check_pose,
    choose_normalisation,
    image_size,
    load_image_stack,
    make_split,
)
from voxnero.errors import DataError

_CAM_RE = re.compile(r"^(.+)-camera\.pkl$")


class _NumpyUnpickler(pickle.Unpickler):
    """Unpickler that only allows numpy array reconstruction."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
        ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
        ("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.numeric", "_frombuffer"),
        ("numpy._core.numeric", "_frombuffer"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"refusing to load {module}.{name}")


def is_nero(root: Path) -> bool:
    """True if ``root`` holds ``*-camera.pkl`` files."""
    return any(root.glob("*-camera.pkl"))


def _view_ids(root: Path) -> list[str]:
    ids = [m.group(1) for p in root.glob("*-camera.pkl") if (m := _CAM_RE.match(p.name))]
    return sorted(ids, key=lambda s: (0, int(s), s) if s.isdigit() else (1, 0, s))


def _read_camera(path: Path) -> tuple[np.ndarray, np.ndarray]:
    try:
        with open(path, "rb") as f:
            obj = _NumpyUnpickler(f).load()
    except Exception as e:  # truncated/corrupt pickles raise many types
        raise DataError(f"cannot read camera pickle ({type(e).__name__}: {e})", path=path,
                        fix="the file must hold a pickled [pose (3x4 world-to-camera), K (3x3)]"
                        ) from None
    if not isinstance(obj, (list, tuple)) or len(obj) < 2:
        raise DataError("camera pickle is not a list [pose, K]", path=path,
                        fix="the file must hold a pickled [pose (3x4 world-to-camera), K (3x3)]")
    pose = check_pose(obj[0], (3, 4), "pose", path)
    K = check_pose(obj[1], (3, 3), "intrinsics K", path)
    return pose, K


def _split_ids(root: Path, split: str, all_ids: list[str]) -> list[str]:
    sfile = root / "split.json"
    if not sfile.is_file():
        if split == "train":
            return all_ids
        raise DataError(f"split {split!r} asked for, but NeRO scenes have no split list (every "
                        "view is 'train')", path=root,
                        fix=f'write {sfile} like {{"train": [0, 1], "{split}": [2]}}')
    try:
        data = json.loads(sfile.read_text())
        ids = [str(v) for v in data[split]]
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise DataError(f"split {split!r} not readable from the split list ({e!r})", path=sfile,
                        fix=f'split.json must map split names to id lists, e.g. '
                            f'{{"{split}": [0, 1]}}') from None
    unknown = sorted(set(ids) - set(all_ids))
    if unknown:
        raise DataError(f"split {split!r} lists views without a camera file: {unknown[:5]}",
                        path=sfile, fix="remove them or add their -camera.pkl files")
    return ids


def load_nero(root: str | Path, splits=("train",), white_bg: bool = False, radius=None,
              center=None, bbox=None, eval_extras: bool = False) -> Scene:
    """Load a NeRO GlossySynthetic scene (see the module docstring).

    The normalisation is computed from all views' cameras; with ``eval_extras`` the
    ``{k}-depth.png`` maps are loaded as ``Split.depth`` (unit frame, 0 = background).
    """
    from voxnero.io.images import read_image

    root = Path(root)
    all_ids = _view_ids(root)
    if not all_ids:
        raise DataError("no '*-camera.pkl' files", path=root, fix="not a NeRO scene folder?")
    cams = {k: _read_camera(root / f"{k}-camera.pkl") for k in all_ids}
    paths = {k: root / f"{k}.png" for k in all_ids}
    w, h = image_size(paths[all_ids[0]])
    c2w_all = np.stack([w2c_to_c2w(cams[k][0]) for k in all_ids])
    K_all = np.stack([cams[k][1] for k in all_ids])
    for i, k in enumerate(all_ids):
        check_camera(K_all[i], c2w_all[i], w, h, f"view {i} ({k}.png)",
                     root / f"{k}-camera.pkl")
    norm, rec = choose_normalisation(c2w_all, K_all, w, h, bbox=bbox, radius=radius,
                                     center=center)
    out, any_alpha = {}, False
    for s in splits:
        ids = _split_ids(root, s, all_ids)
        if not ids:
            raise DataError(f"split {s!r} is empty", path=root / "split.json",
                            fix="list at least one view id")
        enc = load_image_stack([paths[k] for k in ids], w, h, s)
        depth = None
        if eval_extras and all((root / f"{k}-depth.png").is_file() for k in ids):
            depth = np.stack([read_image(root / f"{k}-depth.png")[..., 0] for k in ids])
            if depth.shape[1:] != (h, w):
                raise DataError("depth maps do not match the image size", path=root,
                                fix="depth maps must have the images' size")
            depth = depth.astype(np.float64) * 15.0
            depth[depth >= 14.5] = 0.0
        idx = [all_ids.index(k) for k in ids]
        sp = make_split(s, enc, K_all[idx], c2w_all[idx], norm, ids, white_bg, None, depth)
        any_alpha |= sp.alpha is not None
        out[s] = sp
    return Scene(root=root, format="nero", splits=out, norm=norm, up=np.array([0.0, 0.0, 1.0]),
                 background="alpha" if any_alpha else "unknown",
                 meta={"normalisation": rec, "up_method": "Blender convention (+Z)",
                       "white_bg": bool(white_bg), "n_views": len(all_ids)})
