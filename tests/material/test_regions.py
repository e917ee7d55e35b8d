"""Two materials or one: the two-means split of the per-vertex material and the field's split."""

from __future__ import annotations

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.material.stage2_scene import sphere_geometry
from voxnero.material.field import VertexMaterial, activated, surface_materials
from voxnero.material.regions import two_materials, two_means


def _blobs(n0: int, n1: int, gap: float, spread: float, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    a = 0.3 + spread * torch.randn(n0, 4, generator=g)
    b = 0.3 + spread * torch.randn(n1, 4, generator=g)
    b[:, 3] += gap  # e.g. roughness 0.3 against 0.3 + gap
    return torch.cat([a, b])


def test_two_clear_materials_are_split_along_their_true_boundary():
    x = _blobs(600, 400, 0.4, 0.03)
    sp = two_materials(x, 0.25, 0.1)
    assert sp.accepted
    assert abs(sp.distance - 0.4) < 0.02
    assert abs(sp.fraction - 0.4) < 1e-6
    # the larger cluster is 0: the first 600 rows, with no vertex misplaced
    assert torch.equal(sp.labels, torch.cat([torch.zeros(600), torch.ones(400)]).long())


def test_one_material_with_noise_or_a_small_speck_stays_one():
    noisy = _blobs(1000, 0, 0.0, 0.04)
    assert not two_materials(noisy, 0.25, 0.1).accepted  # centres ~0.13 apart
    speck = _blobs(960, 40, 0.6, 0.02)  # 4 % of the vertices: too few to count
    sp = two_materials(speck, 0.25, 0.1)
    assert sp.distance > 0.5 and not sp.accepted


@settings(max_examples=40, deadline=None)
@given(st.integers(20, 300), st.integers(20, 300), st.floats(0.0, 1.0), st.integers(0, 10**6))
def test_split_is_the_documented_rule_and_labels_are_a_two_means_fixed_point(n0, n1, gap, seed):
    x = _blobs(n0, n1, gap, 0.05, seed)
    sp = two_materials(x, 0.25, 0.1)
    assert sp.accepted == (sp.distance >= 0.25 and sp.fraction >= 0.1)
    assert sp.fraction <= 0.5
    # every vertex sits with its nearer centre (Lloyd's fixed point)
    assert torch.equal(torch.cdist(x, sp.centres).argmin(1), sp.labels)
    labels, _ = two_means(x.flip(0))
    assert labels.shape == (n0 + n1,)


def test_field_split_keeps_albedo_and_roughness_and_restarts_metalness():
    geom = sphere_geometry(0.5, 12)
    f = VertexMaterial(geom, 0.5, 0.9, 0.4)
    top = (geom.vertices[:, 2] > 0).long()
    with torch.no_grad():
        f.residual.normal_(0.0, 0.3, generator=torch.Generator().manual_seed(1))
        f.residual[:, 4] += 2.0 * top
    before = activated(f.raw)
    f.split(top, 0.05)
    after = activated(f.raw)
    assert f.split_done
    assert torch.allclose(after[:, [0, 1, 2, 4]], before[:, [0, 1, 2, 4]], atol=1e-5)
    assert torch.allclose(after[:, 3], torch.full_like(after[:, 3], 0.05), atol=1e-5)
    # each region's base is its median: the residuals are centred on their own material
    for k in (0, 1):
        med = torch.median(f.residual[top == k], 0).values
        assert med.abs().max() < 1e-5
    # and the interpolated value at a vertex is the vertex's value
    v = 5
    t = int((geom.triangles == v).any(1).nonzero()[0, 0])
    bary = (geom.triangles[t] == v).float()[None]
    a, m, r = f(torch.tensor([t]), bary)
    assert torch.allclose(torch.cat([a, m, r], 1)[0], after[v], atol=1e-5)


def test_split_field_renders_and_exports_each_triangle_as_one_material():
    """After a split every triangle is one material (its vertices' majority), in training
    renders and in the export, which cuts the mesh along the boundary: at each corner of each
    triangle the exported value equals the rendered one, and no triangle blends the two."""
    geom = sphere_geometry(0.5, 12)
    f = VertexMaterial(geom, 0.5, 0.5, 0.4)
    top = (geom.vertices[:, 2] > 0.05).long()
    with torch.no_grad():
        f.residual[:, 4] += 3.0 * top  # rough top, smoother bottom
    f.split(top, 0.05)
    vid, tris, a, m, r = surface_materials(f, geom)
    assert torch.equal(vid[tris], geom.triangles.long())  # same surface, same triangle order
    boundary = int((top[geom.triangles].sum(1) % 3 != 0).sum())
    assert boundary > 0 and len(vid) > geom.n_vertices  # boundary vertices were duplicated
    F = geom.triangles.shape[0]
    t = torch.arange(F).repeat_interleave(3)
    bary = torch.eye(3).repeat(F, 1)
    ra, rm, rr = f(t, bary)
    assert torch.allclose(rr, r[tris.reshape(-1)], atol=1e-6)
    assert torch.allclose(ra, a[tris.reshape(-1)], atol=1e-6)
    # within a triangle the roughness is one material's: corners differ by the residual only
    spread = rr.view(F, 3).amax(1) - rr.view(F, 3).amin(1)
    assert float(spread.max().detach()) < 1e-5
