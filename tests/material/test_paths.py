"""Light paths on the mesh (voxnero/material/render.py ``Paths``) against closed forms: a mirror
facing a mirror (how many bounces are visible), a white furnace inside a closed shell with a
port, the energy of paths cut after two bounces, Russian roulette, and the gradient carried
back to the material at a traced bounce."""

from __future__ import annotations

import math

import numpy as np
import open3d as o3d
import pytest
import torch

from voxnero.material.lights import IndirectLight
from voxnero.material.render import Bounces, Paths, Strategies
from voxnero.material.surface import Geometry

H = 0.2  # gap between the two mirrors
THETA = math.radians(60.0)  # angle of the reflected ray from the mirrors' normals
STEP = H * math.tan(THETA)  # sideways run of the ray between two hits
COLOR = 0.8  # metal base colour = F0


def _plates() -> Geometry:
    """Two square mirrors, x, y in [-1, 1]: z = 0 facing up and z = H facing down."""
    v = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0],
                  [-1, -1, H], [1, -1, H], [1, 1, H], [-1, 1, H]], dtype=np.float64)
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]])
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(f))
    m.compute_vertex_normals()
    return Geometry.from_legacy(m)


def _uniform(albedo, metallic, roughness):
    def material(tri, bary, x=None):
        n = tri.shape[0]
        return albedo.expand(n, 3), metallic.expand(n, 1), roughness.expand(n, 1)
    return material


def _schlick(c: float, cos: float) -> float:
    return c + (1 - c) * (1 - cos) ** 5


def _mirror_points(x0: float, n: int):
    """n copies of the point (x0, 0) on the lower mirror, seen from the direction whose mirror
    reflection leaves toward +x at THETA from the normal."""
    tri = torch.zeros(n, dtype=torch.long)  # triangle 0 of the lower mirror: (x0, 0) with x0 > y
    x = torch.tensor([[x0, 0.0, 0.0]]).expand(n, 3)
    a, b = x0, 0.0  # barycentrics of (x0, 0) in the triangle (-1,-1), (1,-1), (1,1)
    bary = torch.tensor([[(1 - a) / 2, (a - b) / 2, (1 + b) / 2]]).expand(n, 3)
    nrm = torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3)
    v = torch.tensor([[-math.sin(THETA), 0.0, math.cos(THETA)]]).expand(n, 3)
    return tri, bary, x, nrm, v


def _hits_after(x0: float) -> int:
    """Further mirror hits of the reflected ray before it leaves the plates (|x| <= 1)."""
    return int(math.floor((1.0 - x0) / STEP + 1e-9))


def _render_mirrors(x0, bounces, albedo=None, n=64, seed=0, spp=Strategies(2, 4, 0)):
    geom = _plates()
    albedo = torch.full((1, 3), COLOR) if albedo is None else albedo
    mat = _uniform(albedo, torch.ones(1, 1), torch.full((1, 1), 0.05))
    paths = Paths(geom, mat, lambda d: torch.ones_like(d), None, "traced", None, bounces,
                  torch.Generator().manual_seed(seed))
    return paths.shade(*_mirror_points(x0, n), spp)


# x0 with 0, 1, 2 and 3 further hits (kept away from the plates' edge)
X0 = {0: 1 - 0.5 * STEP, 1: 1 - 1.5 * STEP, 2: 1 - 2.5 * STEP, 3: 1 - 3.5 * STEP}


@pytest.mark.parametrize("k", [0, 1, 2, 3])
def test_mirror_facing_a_mirror_shows_as_many_bounces_as_traced(k):
    """The ray bounces k more times between the mirrors before it sees the env (radiance 1):
    L = F^(k + 1) with Schlick's F at THETA (GGX at r = 0.05 loses < 1 % at 60°). A path
    cut before its last bounce (no tail) brings 0, i.e. exactly ``traced`` bounces are seen."""
    x0 = X0[k]
    assert _hits_after(x0) == k
    expect = _schlick(COLOR, math.cos(THETA)) ** (k + 1)
    for traced in range(4):
        out = _render_mirrors(x0, Bounces(traced, 0, 1.0, Strategies(0, 1, 0)))
        mean = float(out.mean())
        if traced >= k:
            assert abs(mean - expect) < 0.02 * expect, (k, traced, mean, expect)
        else:
            assert mean < 0.01, (k, traced, mean)


def test_russian_roulette_past_the_traced_bounces_is_unbiased():
    """Two traced bounces are not enough for three further hits; two more by Russian roulette
    (survive 0.5, weight 2) give the full F^4 on average, with 0 or 2·F^4 per path (one GGX
    sample per point and per bounce: one path per point)."""
    k = 3
    expect = _schlick(COLOR, math.cos(THETA)) ** (k + 1)
    one = Strategies(0, 1, 0)
    out = _render_mirrors(X0[k], Bounces(2, 2, 0.5, one), n=1000, spp=one)[:, 0]
    se = float(out.std()) / math.sqrt(out.shape[0])
    assert abs(float(out.mean()) - expect) < 4 * se + 0.01 * expect, (out.mean(), expect, se)
    alive = float((out > 0.5 * expect).float().mean())
    assert 0.4 < alive < 0.6, alive  # half the paths survive the one roulette they meet
    assert float(out[out > 0.5 * expect].mean()) == pytest.approx(2 * expect, rel=0.03)


def test_gradient_reaches_the_material_at_traced_bounces():
    """d/dc F(c)^(k+1) = (k + 1) F^k (1 - (1 - cos)^5): the autograd gradient of the traced
    estimate w.r.t. the (shared) base colour matches the closed form, so the inter-reflections
    train the material they show."""
    k = 2
    c = torch.full((1, 3), COLOR, requires_grad=True)
    out = _render_mirrors(X0[k], Bounces(2, 0, 1.0, Strategies(0, 1, 0)), albedo=c, n=32)
    out[:, 0].mean().backward()
    cos = math.cos(THETA)
    F = _schlick(COLOR, cos)
    expect = (k + 1) * F**k * (1 - (1 - cos) ** 5)
    g = float(c.grad[0, 0])
    assert abs(g - expect) < 0.03 * expect, (g, expect)
    assert abs(float(c.grad[0, 1])) < 1e-6  # the other channels see nothing of channel 0


# ----------------------------------------------------------------------------------------------
# a white furnace inside a closed shell with a port
# ----------------------------------------------------------------------------------------------

PORT = 0.25  # the port's share of the shell's area (a polar cap): the wall's view factor to it


def _shell() -> Geometry:
    """Unit sphere seen from inside (normals inward) with the cap z > 1 - 2·PORT removed."""
    s = o3d.geometry.TriangleMesh.create_sphere(1.0, 30)
    v = np.asarray(s.vertices)
    f = np.asarray(s.triangles)
    keep = v[f].mean(1)[:, 2] < 1 - 2 * PORT
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v),
                                  o3d.utility.Vector3iVector(f[keep][:, ::-1].copy()))
    m.remove_unreferenced_vertices()
    m.compute_vertex_normals()
    return Geometry.from_legacy(m)


def _wall_points(geom: Geometry, n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    d = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
    d = torch.where(d[:, 2:] > 0, -d, d)  # the lower half: far from the port
    _, tri, bary = geom.cast(torch.zeros(n, 3), d)
    assert bool((tri >= 0).all())
    x, nrm = geom.points_at(tri, bary), geom.normals_at(tri, bary)
    v = torch.nn.functional.normalize(-x + 0.3 * torch.randn(n, 3, generator=g), dim=-1)
    v = torch.where((v * nrm).sum(-1, keepdim=True) < 0.1, nrm, v)
    return tri, bary, x, nrm, v


def _render_shell(bounces, tail, n=800, seed=1):
    geom = _shell()
    env = torch.ones(16, 32, 3)
    mat = _uniform(torch.ones(1, 3), torch.zeros(1, 1), torch.ones(1, 1))
    mode = "traced" if bounces is not None else "splitsum"
    paths = Paths(geom, mat, lambda d: torch.ones_like(d), None, mode,
                  IndirectLight(env) if tail else None, bounces,
                  torch.Generator().manual_seed(seed))
    out = paths.shade(*_wall_points(geom, n), Strategies(4, 2, 0))[:, 0]
    return float(out.mean()), float(out.std()) / math.sqrt(n)


def test_white_furnace_inside_a_shell_with_a_port():
    """A white dielectric (albedo 1: directional albedo exactly 1, tests/render) lining a shell
    whose only opening shows radiance 1: the wall is invisible, radiance 1, at any bounce count
    once the split-sum tail (exact under uniform light) ends the path; and with many traced
    bounces plus Russian roulette and no tail."""
    for bounces in (Bounces(0, 0), Bounces(1, 0, 1.0, Strategies(2, 1, 0))):
        mean, se = _render_shell(bounces, tail=True)
        assert abs(mean - 1.0) < 4 * se + 0.02, (bounces, mean, se)
    # one cosine direction per bounce: one path per primary sample, no branching
    mean, se = _render_shell(Bounces(8, 8, 0.7, Strategies(1, 0, 0)), tail=False, n=400)
    # paths longer than 17 hits are cut: (1 - PORT)^17 = 0.7 % of the light
    assert abs(mean - 1.0) < 4 * se + 0.02, (mean, se)


def test_energy_of_paths_cut_after_one_and_two_bounces():
    """Without a tail, wall interactions up to k = traced + 1: light reaching the eye is the
    part that found the port within k bounces, 1 − (1 − PORT)^k for a Lambertian wall (the
    wall sees the port with view factor PORT from everywhere on a sphere). Our white
    dielectric at roughness 1 is near-Lambertian: within 0.03. Never above 1, and growing."""
    prev = 0.0
    for traced in (0, 1, 2):
        b = Bounces(traced, 0, 1.0, Strategies(2, 1, 0))
        mean, se = _render_shell(b, tail=False)
        expect = 1 - (1 - PORT) ** (traced + 1)
        assert abs(mean - expect) < 4 * se + 0.03, (traced, mean, expect, se)
        assert mean <= 1 + 4 * se and mean > prev, (traced, mean, prev)
        prev = mean
