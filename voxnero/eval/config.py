"""``EvalConfig``: the ``eval:`` section of a preset (``voxnero eval ... key=value``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from voxnero.errors import ConfigError


@dataclass
class EvalConfig:
    """Settings of ``voxnero eval``. Defaults are the project's protocol; change them only to
    explore, and say so next to any number you report."""

    split: str = "test"
    """Split of the scene holding the ground truth (masks, depth, normals)."""
    voxel: float = 0.01
    """Chamfer downsampling voxel, in the scene's input-frame units."""
    pred_pixels: Literal["unambiguous", "mask", "all"] = "unambiguous"
    """Pixels giving predicted Chamfer points (see :mod:`voxnero.eval.chamfer`)."""
    normal_source: Literal["vertex", "face"] = "vertex"
    """Predicted normals: interpolated vertex normals or face normals at the ray hit."""
    views: list[int] | None = None
    """Subset of view indices to evaluate (None: all views of the split)."""
    images: int = 2
    """Number of views written as normal-map comparison PNGs (0: none)."""

    def validate(self) -> None:
        if self.voxel < 0:
            raise ConfigError(f"eval.voxel={self.voxel} must be >= 0 (0: no downsampling)")
        if self.images < 0:
            raise ConfigError(f"eval.images={self.images} must be >= 0")
