"""Shared helpers of the pipeline-level stability tests (tests/stability/).

A tiny stage-1 model (coarse SDF grid initialised to a sphere, small env map), a material head
replaced by constants (so the shading is known), and checks that every value and gradient is
finite.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from voxnero.config import from_dict
from voxnero.shape.config import ShapeConfig
from voxnero.shape.renderer import ShapeModel, Switches

S_SCHEDULED_MAX = ShapeConfig().neus.s_end
"""Largest NeuS sharpness the default schedule reaches (1/length, unit frame)."""


def tiny_shape_config(**over) -> ShapeConfig:
    """A small stage-1 config: 32³ SDF grid, 16-row env map, few samples (fast on a CPU)."""
    d = {"grid": {"res": [32], "upsample_at": []}, "light": {"env_height": 16},
         "sampling": {"coarse": 32, "fine": 16, "coarse_keep": 16}}
    for k, v in over.items():
        if isinstance(v, dict):
            d.setdefault(k, {}).update(v)
        else:
            d[k] = v
    return from_dict(ShapeConfig, d)


class ConstantMaterial(nn.Module):
    """Material head stand-in: the same (albedo, metallic, roughness) for every feature."""

    def __init__(self, albedo: float, metallic: float, roughness: float):
        super().__init__()
        self.albedo, self.metallic, self.roughness = albedo, metallic, roughness

    def forward(self, feat: torch.Tensor):
        n = feat.shape[0]
        one = feat[:, :1] * 0.0 + 1.0  # keeps the graph (and the device) of the features
        return (one.expand(n, 3) * self.albedo, one * self.metallic, one * self.roughness)


def tiny_model(cfg: ShapeConfig | None = None, material: tuple[float, float, float] | None = None
               ) -> ShapeModel:
    """A stage-1 model without occlusion/indirect nets; optional constant material."""
    torch.manual_seed(0)
    m = ShapeModel(cfg or tiny_shape_config(), Switches(indirect=False, occlusion=False))
    if material is not None:
        m.material = ConstantMaterial(*material)
    return m


def set_env(model: ShapeModel, image: torch.Tensor) -> None:
    """Set the learnable env map to the linear radiance ``image (H, 2H, 3)``."""
    with torch.no_grad():
        model.env.log_radiance.copy_(image.clamp_min(1e-30).log())


def spot_env(height: int, direction: torch.Tensor, base: float = 0.01, peak: float = 50.0,
             width_deg: float = 6.0) -> torch.Tensor:
    """``(H, 2H, 3)`` env map: constant ``base`` plus a Gaussian spot of ``peak`` around the unit
    world ``direction`` (angular sigma ``width_deg``), in the project's env mapping."""
    from voxnero.render.latlong import pixel_dirs

    d = pixel_dirs(height, 2 * height)
    cos = (d * direction.to(d.dtype)).sum(-1, keepdim=True).clamp(-1, 1)
    ang = torch.acos(cos)
    sig = math.radians(width_deg)
    return (base + peak * torch.exp(-0.5 * (ang / sig) ** 2)).expand(-1, -1, 3).float()


def assert_finite_grads(module: nn.Module, what: str = "") -> int:
    """Assert every existing ``.grad`` of ``module`` is finite; return how many exist."""
    n = 0
    for name, p in module.named_parameters():
        if p.grad is None:
            continue
        n += 1
        assert torch.isfinite(p.grad).all(), f"{what}: non-finite gradient of {name}"
    return n
