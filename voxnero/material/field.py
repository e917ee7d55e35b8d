"""Material fields over the fixed surface: albedo (linear RGB), metallic, perceptual roughness.

Two explicit parameterisations (``material.field.kind``):

* ``vertex``: 5 raw values per mesh vertex, interpolated barycentrically at a hit; smoothness is
  a mean over mesh edges of the difference of neighbouring values.
* ``grid``: a dense ``R³`` grid of raw values over the unit cube ``[-1, 1]³``, trilinear
  (``grid_sample``, ``align_corners=True``); smoothness is the same mean over neighbouring cells.

The difference ``d`` of two neighbours (5 values) is measured by ``SMOOTH_NORMS``:

* ``"l2"``: ``|d|²`` of the activated values (quadratic: a slow ramp over n edges costs J²/n,
  next to nothing on a fine mesh);
* ``"l1"``: ``sqrt(|d|² + eps²) − eps`` of the RAW values (total variation, Charbonnier-smoothed:
  a ramp and a step of the same height J cost the same J per crossing, so materials come out
  piecewise constant and a ramp that only imitates shading is not free; see
  ``FieldConfig.smooth_norm``). Raw, not activated: the total variation of sigmoid outputs falls
  when the values saturate, and with it the roughness of a whole object was driven to its floor
  (weight 0.5: table 0.55 -> 0.035; docs/STAGE2.md).

Both are a **global base** (5 raw values shared by the whole surface) plus a spatial residual
(initialised to 0, kept small by an L2 penalty). Every pixel of every batch trains the base, so a
uniform material converges in a few hundred steps, while each vertex / cell only sees the few
pixels around it (measured on torus_ceramic: per-vertex values alone had moved metallic only from
0.5 to 0.34 after 1000 steps).

The vertex field can hold two materials: :meth:`VertexMaterial.split` gives the vertices of the
second a base of their own (``field.regions``, decided by :mod:`voxnero.material.regions`), and
:meth:`VertexMaterial.hold_metal` fixes metalness per material (0 or 1; ``field.metal`` = race).

Raw values pass through a sigmoid: albedo in (0, 1)³, metallic in (0, 1), roughness r in
(``microfacet.ROUGHNESS_MIN``, 1) (GGX alpha = r², see ``voxnero.render.brdf``).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from voxnero.material.surface import Geometry
from voxnero.mesh.normal_filter import mesh_edges
from voxnero.render.microfacet import raw_from_roughness, roughness_from_raw

SMOOTH_NORMS = ("l2", "l1")
"""How the smoothness measures the difference of two neighbours (see the module docstring)."""
_TV_EPS = 1e-3
"""Charbonnier epsilon of the ``"l1"`` norm (raw units)."""


def edge_penalty(d: Tensor, norm: str) -> Tensor:
    """Per-pair penalty of neighbour differences.

    Args:
        d: (..., 5) differences between neighbours, along the last dim.
        norm: one of ``SMOOTH_NORMS``.

    Returns:
        (...) penalty: ``|d|²`` ("l2") or ``sqrt(|d|² + eps²) − eps`` ("l1").
    """
    sq = (d**2).sum(-1)
    if norm == "l2":
        return sq
    if norm == "l1":
        return torch.sqrt(sq + _TV_EPS**2) - _TV_EPS
    raise ValueError(f"unknown smoothness norm {norm!r}; expected one of {SMOOTH_NORMS}")


def _logit(p: float) -> float:
    p = min(max(p, 1e-4), 1 - 1e-4)
    return math.log(p / (1 - p))


def activated(raw: Tensor) -> Tensor:
    """Raw (..., 5) -> (..., 5) activated values: sigmoid, the roughness channel mapped onto
    [``microfacet.ROUGHNESS_MIN``, 1] (so its gradient never vanishes at the BRDF's clamp)."""
    return torch.cat([torch.sigmoid(raw[..., :4]), roughness_from_raw(raw[..., 4:5])], -1)


def activate(raw: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Raw (..., 5) -> albedo (..., 3), metallic (..., 1) in (0, 1), roughness (..., 1) in
    (``microfacet.ROUGHNESS_MIN``, 1)."""
    s = activated(raw)
    return s[..., 0:3], s[..., 3:4], s[..., 4:5]


def _init_raw(albedo: float, metallic: float, roughness: float) -> list[float]:
    return [_logit(albedo)] * 3 + [_logit(metallic), raw_from_roughness(roughness)]


class VertexMaterial(nn.Module):
    """Per-vertex material parameters on a mesh."""

    def __init__(self, geom: Geometry, albedo: float = 0.5, metallic: float = 0.2,
                 roughness: float = 0.4):
        """Args:
            geom: the mesh (its triangles define the interpolation and the edges).
            albedo, metallic, roughness: initial values everywhere.
        """
        super().__init__()
        self.geom = geom
        self.base = nn.Parameter(torch.tensor(_init_raw(albedo, metallic, roughness)))
        self.residual = nn.Parameter(torch.zeros(geom.n_vertices, 5))
        # second material's base, as an offset from ``base`` (unused until :meth:`split`)
        self.shift = nn.Parameter(torch.zeros(1, 5))
        self.register_buffer("region", torch.zeros(geom.n_vertices, dtype=torch.long))
        # material of each triangle after a split: the majority of its vertices' regions
        self.register_buffer("face_region", torch.zeros(geom.triangles.shape[0],
                                                        dtype=torch.long))
        # metalness held per region (-1: learned freely), see hold_metal
        self.register_buffer("metal_fixed", torch.full((2,), -1.0))
        # whether ``region`` marks a split, kept as a flag so that every forward (the hot path)
        # does not reduce over the vertices (a device sync on CUDA); refreshed on loading
        self._split = False
        self.register_load_state_dict_post_hook(
            lambda module, _keys: setattr(module, "_split", bool(module.region.any())))
        self.register_buffer("edges", mesh_edges(geom.triangles), persistent=False)

    def forward(self, tri: Tensor, bary: Tensor, x: Tensor | None = None
                ) -> tuple[Tensor, Tensor, Tensor]:
        """Material at surface points.

        Args:
            tri: (N,) triangle indices (>= 0); bary: (N, 3) barycentrics; x: unused.

        Returns:
            albedo (N, 3), metallic (N, 1), roughness (N, 1).
        """
        raw = self.base + self.geom.interpolate(self.residual, tri, bary)
        if self.split_done:  # each triangle is one material: the boundary stays sharp
            raw = raw + self._shifts()[self.face_region[tri]]
        return activate(raw)

    def _shifts(self) -> Tensor:
        """(2, 5) raw offset of each region's base from ``base`` (region 0: zero)."""
        return torch.cat([torch.zeros_like(self.shift), self.shift])

    def _offsets(self) -> Tensor:
        """(V, 5) raw offsets from ``base``: the vertex's region shift + residual."""
        if not self.split_done:
            return self.residual
        return self.residual + self._shifts()[self.region]

    @property
    def split_done(self) -> bool:
        """Whether the surface was split into two materials (:meth:`split`)."""
        return self._split

    @property
    def raw(self) -> Tensor:
        """(V, 5) raw values at the vertices (base + region shift + residual)."""
        return self.base + self._offsets()

    @torch.no_grad()
    def split(self, labels: Tensor, metallic_restart: float) -> None:
        """Give the vertices of ``labels`` == 1 a base of their own and restart metalness.

        The raw albedo and roughness do not change: each region's base becomes the median of
        its vertices' values and the residuals are re-expressed around it (so the residual
        penalty now pulls each vertex toward its own material, not toward a mix of the two).
        Metalness restarts at ``metallic_restart`` everywhere (residuals 0): the shared base
        had one value for both materials, which is what this corrects.

        Args:
            labels: (V,) long in {0, 1}.
            metallic_restart: activated metallic both regions start from again, in (0, 1).
        """
        labels = labels.to(self.region.device)
        c = [torch.median(self.residual[labels == k], 0).values for k in (0, 1)]
        self.base += c[0]
        self.shift.copy_((c[1] - c[0])[None])
        self.residual -= torch.stack(c)[labels]
        self.region.copy_(labels)
        self._split = bool(labels.any())
        self.face_region.copy_((labels[self.geom.triangles].sum(1) >= 2).long())
        self.base[3] = _logit(metallic_restart)
        self.shift[:, 3] = 0.0
        self.residual[:, 3] = 0.0

    @torch.no_grad()
    def hold_metal(self, values: tuple[float, ...]) -> None:
        """Hold metalness at ``values`` (one per region: 0 dielectric, 1 metal) from now on;
        :meth:`impose_metal` re-applies it after every optimiser step."""
        self.metal_fixed.fill_(-1.0)
        self.metal_fixed[: len(values)] = torch.tensor(values, dtype=self.metal_fixed.dtype)
        self.impose_metal()

    @property
    def metal_held(self) -> bool:
        """Whether metalness is held (:meth:`hold_metal`)."""
        return bool(self.metal_fixed[0] >= 0)

    @torch.no_grad()
    def impose_metal(self) -> None:
        """Set the raw metallic channel to the held values (no-op when none are held): the
        activated value is 1e-4 from 0 or 1 (``_logit``'s clamp)."""
        if not self.metal_held:
            return
        held = [float(v) for v in self.metal_fixed]
        self.base[3] = _logit(held[0])
        if self.split_done and held[1] >= 0:
            self.shift[0, 3] = _logit(held[1]) - _logit(held[0])
        self.residual[:, 3] = 0.0

    def residual_penalty(self) -> Tensor:
        """Mean squared residual (keeps the spatial part small where data is weak)."""
        return (self.residual**2).mean()

    def smoothness(self, sample: int = 65536, generator: torch.Generator | None = None,
                   norm: str = "l2") -> Tensor:
        """Mean over (a random subset of) edges of :func:`edge_penalty` (activated values for
        "l2", raw for "l1"), without the regions' shifts: after a split the boundary between
        the two materials is free, each material stays piecewise constant around its base."""
        e = self.edges
        if sample and e.shape[0] > sample:
            e = e[torch.randint(0, e.shape[0], (sample,), generator=generator).to(e.device)]
        s = self.base + self.residual
        if norm != "l1":
            s = activated(s)
        return edge_penalty(s[e[:, 0]] - s[e[:, 1]], norm).mean()


class GridMaterial(nn.Module):
    """Dense trilinear grid of material parameters over the unit cube."""

    def __init__(self, res: int = 48, albedo: float = 0.5, metallic: float = 0.2,
                 roughness: float = 0.4, bound: float = 1.0):
        """Args:
            res: grid resolution per axis.
            albedo, metallic, roughness: initial values everywhere.
            bound: the grid covers ``[-bound, bound]³`` (unit frame).
        """
        super().__init__()
        self.base = nn.Parameter(torch.tensor(_init_raw(albedo, metallic, roughness)))
        self.grid = nn.Parameter(torch.zeros(1, 5, res, res, res))
        self.bound = bound

    def raw_at(self, x: Tensor) -> Tensor:
        """(N, 3) points -> (N, 5) raw values (trilinear)."""
        # grid_sample's (x, y, z) index the tensor axes (W, H, D): the grid is stored (z, y, x)
        g = (x / self.bound).view(1, -1, 1, 1, 3)
        out = F.grid_sample(self.grid, g, mode="bilinear", padding_mode="border",
                            align_corners=True)
        return self.base + out.view(5, -1).T

    def residual_penalty(self) -> Tensor:
        """Mean squared residual of the grid cells."""
        return (self.grid**2).mean()

    def forward(self, tri: Tensor, bary: Tensor, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Material at surface points ``x`` (N, 3); tri/bary unused. Returns as VertexMaterial."""
        return activate(self.raw_at(x))

    def smoothness(self, sample: int = 0, generator: torch.Generator | None = None,
                   norm: str = "l2") -> Tensor:
        """Sum over the three axes of the mean :func:`edge_penalty` of neighbouring cells
        (activated values for "l2", raw for "l1"; ``sample`` and ``generator`` unused)."""
        s = (self.grid + self.base.view(1, 5, 1, 1, 1)).movedim(1, -1)
        if norm != "l1":
            s = activated(s)
        return sum(edge_penalty(s.narrow(d, 1, s.shape[d] - 1) - s.narrow(d, 0, s.shape[d] - 1),
                                norm).mean() for d in (1, 2, 3))


def make_field(kind: str, geom: Geometry, grid_res: int, albedo: float, metallic: float,
               roughness: float) -> VertexMaterial | GridMaterial:
    """The material field named by ``material.field.kind``."""
    if kind == "vertex":
        return VertexMaterial(geom, albedo, metallic, roughness)
    return GridMaterial(grid_res, albedo, metallic, roughness)


def surface_materials(field: VertexMaterial | GridMaterial, geom: Geometry
                      ) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """The material as per-vertex values of a mesh to bake (exports).

    A vertex field split into two materials is returned on the mesh **cut along the
    boundary**: a vertex used by triangles of both materials appears once per material, so
    per-vertex interpolation (texture baking, renderers) keeps the boundary as sharp as the
    training render (:meth:`VertexMaterial.forward`). Otherwise the mesh's own vertices.

    Returns:
        ``vid`` (P,) long: the mesh vertex of each output vertex; ``triangles`` (F, 3) long into
        the output vertices (same triangle order as the mesh); albedo (P, 3), metallic (P, 1),
        roughness (P, 1).
    """
    with torch.no_grad():
        if isinstance(field, GridMaterial):
            a, m, r = activate(field.raw_at(geom.vertices))
            return torch.arange(geom.n_vertices), geom.triangles.long(), a, m, r
        if not field.split_done:
            return (torch.arange(geom.n_vertices), geom.triangles.long(), *activate(field.raw))
        tris = geom.triangles.long()
        key = tris * 2 + field.face_region[:, None]
        uniq, inv = torch.unique(key.reshape(-1), return_inverse=True)
        vid, reg = uniq // 2, uniq % 2
        raw = field.base + field.residual[vid] + field._shifts()[reg]
        return (vid, inv.reshape(-1, 3), *activate(raw))
