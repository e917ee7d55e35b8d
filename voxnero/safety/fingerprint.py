"""What a checkpoint was made from, so that a resume with something else is refused.

A fingerprint is ``{"sources": {name: digest}, "settings": {dotted key: value}}``:

* sources: :func:`scene_digest` of the scene (its training cameras, image names and sizes and a
  sample of the pixels, as loaded: the same for a copy or a move of the folder, and for any
  format), :func:`file_digest` of a mesh;
* settings: :func:`model_settings`, the resolved config flattened to dotted keys without the
  keys its class lists in ``FREE_ON_RESUME`` (output, logging and checkpoint cadence: they do
  not change the model), plus the removed keys its class lists in ``RETIRED`` at their one
  remaining value (so that checkpoints from before a removal resume).

:func:`check_resume` compares a checkpoint's fingerprint with the run's and names what differs.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from voxnero.config import to_dict
from voxnero.errors import RunFolderError

FIX = "add --fresh to start over in this folder, or pass another --out"


def _update(h: Any, arr: Any) -> None:
    a = np.ascontiguousarray(np.asarray(arr.detach().cpu() if hasattr(arr, "detach") else arr))
    h.update(f"{a.dtype}{a.shape}".encode())
    h.update(a.tobytes())


def scene_digest(scene: Any, split: str = "train", pixel_stride: int = 7) -> str:
    """Path-independent digest of a loaded scene's ``split``: cameras (intrinsics, poses), the
    image names, the image size and every ``pixel_stride``-th row and column of the photos.

    Args:
        scene: a :class:`voxnero.data.scene.Scene`.
        split: the split the run trains on.
        pixel_stride: stride of the pixel sample (a full hash of 100 photos of 800² costs ~1 s).

    Returns:
        16 hexadecimal digits.
    """
    sp = scene.split(split)
    h = hashlib.sha256()
    for name in ("K", "c2w"):
        value = getattr(sp.cameras, name, None)
        if value is not None:
            value = value.detach().cpu() if hasattr(value, "detach") else value
            _update(h, np.round(np.asarray(value, dtype=np.float64), 6))
    h.update(repr([str(n) for n in getattr(sp, "names", None) or []]).encode())
    _update(h, sp.images[:, ::pixel_stride, ::pixel_stride])
    return h.hexdigest()[:16]


def file_digest(path: str | Path) -> str:
    """sha256 of a file's bytes (16 hexadecimal digits)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:16]


def _flatten(d: Any, prefix: str = "") -> dict[str, Any]:
    if not isinstance(d, dict):
        return {prefix: d}
    out: dict[str, Any] = {}
    for k, v in d.items():
        out.update(_flatten(v, f"{prefix}{k}." if isinstance(v, dict) else f"{prefix}{k}"))
    return out


def model_settings(cfg: Any) -> dict[str, Any]:
    """The settings of a config dataclass that shape the model: flattened dotted keys, without
    the class's ``FREE_ON_RESUME`` keys."""
    free = set(getattr(cfg, "FREE_ON_RESUME", ()))
    out = {k: v for k, v in _flatten(to_dict(cfg)).items() if k not in free}
    out.update(getattr(cfg, "RETIRED", {}))  # removed keys: old checkpoints still match
    return out


def make(cfg: Any, **sources: str) -> dict[str, Any]:
    """The fingerprint of a run of ``cfg`` on ``sources`` (name -> digest)."""
    return {"sources": dict(sources), "settings": model_settings(cfg)}


def _short(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 40 else s[:37] + "..."


def check_resume(saved: dict[str, Any] | None, now: dict[str, Any], ckpt: str | Path,
                 section: str = "") -> bool:
    """Refuse a resume whose checkpoint was made from another scene/mesh or other settings.

    Args:
        saved: the checkpoint's fingerprint (None: a checkpoint from before fingerprints).
        now: this run's fingerprint (:func:`make`).
        ckpt: the checkpoint file (named in the error).
        section: config section prefixed to the keys named (``shape``).

    Returns:
        False for a checkpoint without a fingerprint (nothing checked), else True.

    Raises:
        RunFolderError: what differs, and the fix (``--fresh`` or another ``--out``).
    """
    if not saved:
        return False
    for name, digest in now.get("sources", {}).items():
        old = saved.get("sources", {}).get(name)
        if old is not None and old != digest:
            raise RunFolderError(f"this folder's checkpoint was made from another {name} "
                                 f"(fingerprint {old}, this {name}: {digest})", path=ckpt,
                                 fix=FIX)
    a, b = saved.get("settings", {}), now.get("settings", {})
    diff = sorted(k for k in set(a) | set(b) if a.get(k, "<unset>") != b.get(k, "<unset>"))
    if diff:
        pre = f"{section}." if section else ""
        shown = ", ".join(f"{pre}{k}: {_short(a.get(k))} -> {_short(b.get(k))}"
                          for k in diff[:4])
        more = f" and {len(diff) - 4} more" if len(diff) > 4 else ""
        raise RunFolderError(f"this folder's checkpoint was trained with other settings "
                             f"({shown}{more})", path=ckpt,
                             fix=f"{FIX}; or resume with the checkpoint's settings")
    return True
