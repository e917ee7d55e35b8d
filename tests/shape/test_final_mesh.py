"""The exported mesh keeps its field's topology (:func:`voxnero.shape.run_files.final_mesh`).

Reference: the genus of the same trilinear field tessellated 16 times finer (113 samples for an
8³ grid), where refinement has converged on these fields (225 samples give the same genus).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from voxnero.fields.grid import resample
from voxnero.mesh.cleanup import clean_mesh
from voxnero.mesh.extract import extract_mesh
from voxnero.mesh.topology import mesh_topology
from voxnero.shape.run_files import extract, final_mesh, refined_res

BOUNDS = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def random_field(seed: int) -> torch.Tensor:
    """``(1, 8, 8, 8)``: normal values (mean −0.2) in the central 4³ corners, +1 around them."""
    rng = np.random.default_rng(seed)
    g = np.full((8, 8, 8), 1.0)
    g[2:6, 2:6, 2:6] = rng.normal(-0.2, 1.0, (4, 4, 4))
    return torch.tensor(g, dtype=torch.float32)[None]


def model_of(g: torch.Tensor) -> SimpleNamespace:
    return SimpleNamespace(sdf=SimpleNamespace(grid=torch.nn.Parameter(g), bounds=BOUNDS))


def converged_genus(g: torch.Tensor) -> int | None:
    return mesh_topology(clean_mesh(extract_mesh(resample(g, 113)[0].numpy(), BOUNDS)))[0]


def test_refined_res_keeps_the_corners():
    assert refined_res(8) == 15
    assert refined_res(128) == 255
    g = random_field(0)
    assert torch.allclose(resample(g, refined_res(8))[0, ::2, ::2, ::2], g[0], atol=1e-6)


# seeds whose 1.5x resampling (12 samples) adds a handle (21, 32, 78) or loses one (0, 6, 9)
@pytest.mark.parametrize("seed", [21, 32, 78, 0, 6, 9])
def test_a_resampling_pinhole_is_replaced_by_the_refined_mesh(seed):
    g = random_field(seed)
    truth = converged_genus(g)
    plain = mesh_topology(extract(model_of(g), 12))[0]
    assert plain != truth  # the artefact this guards against
    mesh, info = final_mesh(model_of(g), 12)
    assert mesh_topology(mesh)[0] == truth
    assert info == {"mesh_res": 15, "genus": [plain, truth]}


def test_a_mesh_with_the_refined_topology_is_kept_as_extracted():
    """A torus (genus 1) at 40 samples: kept, vertex for vertex."""
    n = 24
    t = torch.linspace(-1.0, 1.0, n)
    z, y, x = torch.meshgrid(t, t, t, indexing="ij")
    sdf = torch.sqrt((torch.sqrt(x**2 + y**2) - 0.55) ** 2 + z**2) - 0.25
    model = model_of(sdf[None])
    mesh, info = final_mesh(model, 40)
    assert info == {"mesh_res": 40, "genus": [1, 1]}
    np.testing.assert_array_equal(np.asarray(mesh.vertices),
                                  np.asarray(extract(model, 40).vertices))
    mesh, info = final_mesh(model, refined_res(n))  # already the reference: measured once
    assert info == {"mesh_res": 47, "genus": [1, None]}
