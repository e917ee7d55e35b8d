"""voxnero/shape/proposals.py: the worst-fitted patch and the opened shell, against closed forms
on a sphere (the race's use of them: tests/shape/test_trainer.py)."""

from __future__ import annotations

import numpy as np
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from voxnero.fields.grid import grid_points
from voxnero.shape.proposals import opened_shell, worst_patch

R = 0.6


def _sphere_points(n: int = 4000, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(n, 3))
    return R * p / np.linalg.norm(p, axis=1, keepdims=True)


def test_worst_patch_is_the_largest_connected_high_error_region():
    """A cap of high error (z > 0.8 R) is returned whole; a single high point elsewhere (a
    smaller component) and the low-error rest are not."""
    p = _sphere_points()
    err = np.full(len(p), 0.02)
    cap = p[:, 2] > 0.8 * R
    err[cap] = 0.06
    lone = np.argmin(p[:, 2])  # the bottom point: high, but alone
    err[lone] = 0.5
    out = worst_patch(p, err, bin_size=0.05, k=1.5)
    got = {tuple(x) for x in out}
    want = {tuple(x) for x in p[cap]}
    assert len(want - got) <= 0.05 * len(want)  # the cap (its rim may blur below the bar)
    assert all(x[2] > 0.6 * R for x in out) and tuple(p[lone]) not in got


def test_worst_patch_of_a_uniform_fit_is_empty_or_tiny():
    p = _sphere_points()
    err = np.random.default_rng(1).uniform(0.019, 0.021, len(p))
    assert len(worst_patch(p, err, 0.05, 1.5)) == 0
    assert len(worst_patch(p[:0], err[:0], 0.05, 1.5)) == 0


@settings(max_examples=8, deadline=None)
@given(tau=st.floats(0.02, 0.08), extra=st.floats(0.0, 0.05))
def test_opened_shell_of_a_ball_is_a_bowl(tau, extra):
    """h = |x| − R hollowed (walls 2τ) and cut within ρ = 2τ + extra of the top cap
    (z > 0.7 R): the centre and the top of the wall are outside, the bottom of the wall
    inside, and outside the ball, away from the cut, nothing changes (f = h there)."""
    res = 41
    corners = grid_points(res, torch.tensor([[-1.0] * 3, [1.0] * 3]))
    h = (corners.norm(dim=-1) - R)[None]
    cap = _sphere_points(20000)
    cap = cap[cap[:, 2] > 0.7 * R]
    rho = 2 * tau + extra
    f = opened_shell(h, corners, cap, tau, rho)

    def at(x, y, z):
        from voxnero.fields.grid import grid_sample_points

        pt = torch.tensor([[x, y, z]], dtype=torch.float32)
        return float(grid_sample_points(f, pt, torch.tensor([[-1.0] * 3, [1.0] * 3]))[0, 0])

    assert at(0, 0, 0) > 0  # hollow
    assert at(0, 0, R - tau) > 0  # the wall under the patch is cut
    voxel = 2.0 / (res - 1)
    assert at(0, 0, -R + tau) < voxel  # the bottom wall stays (within a voxel of trilinear)
    from scipy.spatial import cKDTree

    far = torch.from_numpy(cKDTree(cap).query(corners.reshape(-1, 3).numpy())[0] > rho)
    out = (h > 0).reshape(-1) & far  # outside the ball and away from the cut: unchanged
    assert torch.allclose(f.reshape(-1)[out], h.reshape(-1)[out])


def _sphere_mesh(radius: float = R, resolution: int = 80):
    import open3d as o3d

    return o3d.geometry.TriangleMesh.create_sphere(radius=radius, resolution=resolution)


@settings(max_examples=6, deadline=None)
@given(scale=st.floats(0.05, 1.0))
def test_outer_distance_of_a_sphere_mesh_is_its_closed_form(scale):
    """Points inside, on and outside a tessellated sphere of radius R: the distance is
    ``|x| − R`` within the tessellation's sagitta (negative inside), at every scale of the
    query (the sign from the rays' parity does not depend on how far the point is)."""
    from voxnero.shape.proposals import outer_distance

    rng = np.random.default_rng(0)
    d = rng.normal(size=(500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = rng.uniform(0.0, 2.0 * R, size=(500, 1)) * scale + (1 - scale) * R
    pts = torch.from_numpy(d * r).float()
    got = outer_distance(_sphere_mesh(), pts.reshape(25, 20, 3))
    assert got.shape == (25, 20) and got.dtype == torch.float32
    want = (pts.norm(dim=-1) - R).reshape(25, 20)
    sagitta = R * (1 - np.cos(np.pi / 80))  # the chord's depth at resolution 80
    assert float((got - want).abs().max()) < 2 * sagitta + 1e-4
    far = want.abs() > 2 * sagitta
    assert torch.equal(torch.sign(got[far]), torch.sign(want[far]))


def test_closed_surface_closes_a_solid_at_the_grid_faces():
    """A ball of radius 1.3 on a grid over [-1, 1]³ (32³) crosses every face of the grid: its
    surface is closed there (watertight), and the signed distance inside is the distance to
    the nearest face (the intersection of ball and cube), negative; the sampling sphere
    (radius 1.2) clips it first."""
    from types import SimpleNamespace

    from voxnero.shape.proposals import closed_surface, outer_distance

    bounds = torch.tensor([[-1.0] * 3, [1.0] * 3])
    g = (grid_points(32, bounds).norm(dim=-1) - 1.3)[None]
    sdf = SimpleNamespace(grid=g, bounds=bounds)
    tr = SimpleNamespace(model=SimpleNamespace(sdf=sdf),
                         cfg=SimpleNamespace(sampling=SimpleNamespace(radius=1.2)))
    mesh = closed_surface(tr)
    assert mesh.is_watertight()
    pts = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, -0.7, 0.2]])
    d = outer_distance(mesh, pts)
    voxel = 2.0 / 31
    # the box grows by one voxel; the surface closes between the last corner and the pad
    want = -(1.0 + 0.5 * voxel - pts.abs().max(dim=1).values)
    assert torch.allclose(d, want, atol=0.6 * voxel), (d, want)


def test_open_start_hollows_the_finished_surface_not_the_start_it_replaces():
    """The edit measures the distance to the finished run's surface (a sphere mesh of radius
    R) at the start grid's corners (33³ over [-0.8, 0.8]³, holding a larger ball, the hull):
    the result is the opened shell of the ball of R within the tessellation's error, the
    decision "open" counts the ball's corners inside before the hollowing, not the hull's, and
    records the hold as steps (``hold`` of ``iters``)."""
    from types import SimpleNamespace

    from voxnero.shape.proposals import open_start

    bounds = torch.tensor([[-0.8] * 3, [0.8] * 3])
    corners = grid_points(33, bounds)
    hull = (corners.norm(dim=-1) - 0.75)[None]
    sdf = SimpleNamespace(grid=torch.nn.Parameter(hull.clone()), bounds=bounds, voxel=0.05)
    cfg = SimpleNamespace(grid=SimpleNamespace(bound=1.0), coarse=SimpleNamespace(res=41),
                          iters=1500)
    tr = SimpleNamespace(model=SimpleNamespace(sdf=sdf), cfg=cfg, decisions=[])
    cap = _sphere_points(20000)
    cap = cap[cap[:, 2] > 0.7 * R]
    open_start(cap, 1.0, 0.2, _sphere_mesh())(tr)
    tau = 1.0 * 2.0 / 40
    want = opened_shell((corners.norm(dim=-1) - R)[None], corners, cap, tau, 2 * tau + 0.05)
    err = (sdf.grid.detach() - want).abs()
    assert float(err.max()) < 2 * R * (1 - np.cos(np.pi / 80)) + 1e-4
    ev = tr.decisions[-1].evidence
    ball = int((corners.norm(dim=-1) < R).sum())
    assert abs(ev["inside_before"] - ball) <= 0.01 * ball < int((hull < 0).sum())
    assert ev["inside_after"] == int((sdf.grid < 0).sum()) < ev["inside_before"]
    assert ev["hold_steps"] == 300


class _PaintedModel(torch.nn.Module):
    """A stand-in for the stage-1 model: features are positions, and the material head paints
    metallic 1 and albedo 0.2 where z > 0.8 R (a "lid"), metallic 0 and albedo 0.8 elsewhere,
    roughness 0.5 everywhere; the SDF grid only gives dtype and device."""

    def __init__(self, lid: bool):
        super().__init__()
        self.lid = lid
        self.sdf = type("G", (), {"grid": torch.zeros(1, 2, 2, 2)})()

    def feat(self, x: torch.Tensor) -> torch.Tensor:
        return x

    def material(self, f: torch.Tensor):
        on = (f[:, 2:3] > 0.8 * R).float() if self.lid else torch.zeros_like(f[:, 2:3])
        albedo = (0.8 - 0.6 * on).expand(-1, 3)
        return albedo, on, torch.full_like(on, 0.5)


def test_material_contrast_is_the_largest_material_step_between_patch_and_ring():
    """Patch = the cap z > 0.8 R: painted with another material, the contrast is the metallic
    step 1 (the albedo's is 0.6, roughness 0), the patch's means are the lid's, the ring's the
    wall's; painted like its surroundings the contrast is 0; an empty patch gives 0."""
    from types import SimpleNamespace

    from voxnero.shape.proposals import material_contrast

    p = _sphere_points()
    cap = p[:, 2] > 0.8 * R
    lid = material_contrast(SimpleNamespace(model=_PaintedModel(True)), p, p[cap], 0.05)
    assert lid["contrast"] == 1.0
    assert lid["patch"] == [1.0, 0.5, 0.2, 0.2, 0.2]
    assert lid["ring"] == [0.0, 0.5, 0.8, 0.8, 0.8]
    same = material_contrast(SimpleNamespace(model=_PaintedModel(False)), p, p[cap], 0.05)
    assert same["contrast"] == 0.0
    assert material_contrast(SimpleNamespace(model=_PaintedModel(True)), p, p[:0],
                             0.05)["contrast"] == 0.0


def test_propose_open_proposes_only_a_patch_painted_unlike_its_surroundings(monkeypatch):
    """``propose_open`` with the surface's fit given (a cap of high error): the lid-painted
    cap is proposed (an edit) at ``open_gate`` 0.3; the cap painted like the walls is not
    (``None``, the contrast in the evidence); with ``open_gate`` 0 (the default) it is."""
    from types import SimpleNamespace

    from voxnero.shape import proposals
    from voxnero.shape.config import CoarseConfig

    p = _sphere_points()
    err = np.where(p[:, 2] > 0.8 * R, 0.06, 0.02)
    monkeypatch.setattr(proposals, "surface_error", lambda tr, b: (p, err))
    monkeypatch.setattr(proposals, "closed_surface", lambda tr: _sphere_mesh())
    co = CoarseConfig(res=64, open_gate=0.3)

    def trainer(lid: bool):
        m = _PaintedModel(lid)
        m.sdf.bounds = torch.tensor([[-1.0] * 3, [1.0] * 3])
        return SimpleNamespace(model=m, cfg=SimpleNamespace(grid=SimpleNamespace(bound=1.05)),
                               log=lambda s: None)

    edit, ev = proposals.propose_open(trainer(True), co)
    # the blurred patch may take in a few wall points at the cap's rim
    assert edit is not None and ev["material"]["contrast"] > 0.7 and ev["patch_cubes"] > 0
    edit, ev = proposals.propose_open(trainer(False), co)
    assert edit is None and ev["material"]["contrast"] == 0.0 and ev["gate"] == 0.3
    edit, _ = proposals.propose_open(trainer(False), CoarseConfig(res=64))
    assert edit is not None
