"""Shading normals refined by stage 2 on the fixed mesh.

Stage 1's mesh carries vertex normals a few degrees off the truth (corpus ``standard``: 2-3° on
the knot and the pretzel, 6-9° on the rough objects). A mirror shows a normal error directly: its
reflections move by twice the angle, and a fixed mesh makes the fit blur them with roughness
instead (knot_chrome: roughness 0.16 for 0.03 and 20 dB relit; the same mesh positions with the
true normals: 0.05 and 25.7 dB, docs/BENCHMARKS.md session 25). With ``normals.refine`` the
shading normals learn (off by default: from the photos' Monte Carlo gradients they have not yet
come nearer the truth on the corpus, see :class:`voxnero.material.config.NormalsConfig`).

Parametrisation (unit frame; directions do not change under the project's normalisation)::

    n_v = normalize(n0_v + r_v),   r = A^K θ

with ``n0`` (V, 3) stage 1's unit vertex normals, ``θ`` (V, 3) the learned parameters (zero at
the start) and ``A^K`` ``rounds`` rounds of neighbour averaging over the mesh's edges
(:func:`voxnero.material.regions.mesh_average`): a pixel's gradient reaches a K-ring around its
triangle, so the correction is smooth along the surface by construction (per-vertex values seen
by a few Monte Carlo pixels are noise otherwise), and it follows the mesh's connectivity, so the
two sides of a thin plate do not share it. ``prior · mean |n − n0|²`` keeps the normals near
stage 1's where the photos say little. Positions never move: rays are cast on stage 1's mesh,
only shading sees the normals; the exports carry them as the mesh's vertex normals.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from voxnero.material.regions import mesh_average
from voxnero.mesh.normal_filter import mesh_edges


class RefinedNormals(nn.Module):
    """Learned per-vertex shading normals around a mesh's own (see the module docstring)."""

    def __init__(self, base: Tensor, triangles: Tensor, rounds: int = 8):
        """Args:
            base: (V, 3) unit vertex normals of the fixed mesh (stage 1's).
            triangles: (F, 3) long vertex indices of the mesh.
            rounds: neighbour-averaging rounds between the parameters and the correction.
        """
        super().__init__()
        self.register_buffer("base", base.detach().clone())
        self.register_buffer("edges", mesh_edges(triangles), persistent=False)
        self.rounds = int(rounds)
        self.theta = nn.Parameter(torch.zeros_like(self.base))

    def forward(self) -> Tensor:
        """(V, 3) unit shading normals."""
        r = mesh_average(self.theta, self.edges, self.rounds)
        return torch.nn.functional.normalize(self.base + r, dim=-1)

    def prior(self, normals: Tensor) -> Tensor:
        """Mean squared chord ``|n − n0|²`` = 2 (1 − cos angle) of ``normals`` (:meth:`forward`'s
        output) from the mesh's own."""
        return ((normals - self.base) ** 2).sum(-1).mean()

    @torch.no_grad()
    def angles_deg(self) -> np.ndarray:
        """(V,) angle in degrees of each refined normal from the mesh's own."""
        from voxnero.eval.normals import angle_deg

        return angle_deg(self.forward().double().cpu().numpy(),
                         self.base.double().cpu().numpy())
