"""Per-object materials of synthetic scenes (the project's BRDF parameters).

``albedo`` is the linear base colour; ``metallic`` in [0, 1]; ``roughness`` is the *perceptual*
roughness r in [0, 1] (GGX uses α = r², clamped below at ``voxnero.render.brdf.ALPHA_MIN``).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class Material:
    """Uniform material of one object."""

    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    metallic: float = 0.0
    roughness: float = 0.5

    def to_dict(self) -> dict:
        """JSON form, named like the dev scenes' material.json (``base_color``...)."""
        return {"kind": "uniform", "base_color": [float(c) for c in self.albedo],
                "metallic": float(self.metallic), "roughness": float(self.roughness),
                "roughness_convention": "perceptual r; GGX alpha = r^2"}


@dataclass
class MaterialTable:
    """Materials of K objects stacked for gathering by object index.

    Attributes:
        albedo: (K, 3) linear base colour.
        metallic: (K, 1).
        roughness: (K, 1) perceptual r.
    """

    albedo: torch.Tensor
    metallic: torch.Tensor
    roughness: torch.Tensor

    @classmethod
    def from_materials(cls, materials: list[Material]) -> MaterialTable:
        """Stack a list of :class:`Material` (one per object, in object order)."""
        return cls(torch.tensor([m.albedo for m in materials], dtype=torch.float32),
                   torch.tensor([[m.metallic] for m in materials], dtype=torch.float32),
                   torch.tensor([[m.roughness] for m in materials], dtype=torch.float32))

    def gather(self, obj: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Parameters of objects ``obj`` (N,) long: albedo (N,3), metallic (N,1), rough (N,1)."""
        return self.albedo[obj], self.metallic[obj], self.roughness[obj]
