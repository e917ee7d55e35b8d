"""Tests of voxnero/synth/pathtrace.py: white furnace, mirror reflection law, interreflection.

Monte Carlo tolerances are stated from the estimator's own per-sample standard deviation σ₁,
pooled over all samples of the image (so it is not fitted per pixel): a pixel mean of ``spp``
samples must lie within 5·σ₁/√spp of the expected value, the image mean within 5·σ₁/√(N·spp).
Measured (32², 64 spp, ~220 fully covered pixels): Lambert σ₁ ≈ 0.32·E, so pixels within ±0.20·E
and the image mean within ±0.014·E (observed 1.002·E); white GGX metal σ₁ ≈ 0.27–0.28·E.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from voxnero.cameras.rays import pixel_rays, pixel_samples
from voxnero.render.brdf import brdf_eval
from voxnero.render.envmap import EnvMap
from voxnero.render.latlong import pixel_dirs
from voxnero.synth.camera_rig import make_cameras
from voxnero.synth.envmaps import constant_envmap
from voxnero.synth.materials import Material, MaterialTable
from voxnero.synth.pathtrace import trace_paths
from voxnero.synth.shapes import Sphere, Union
from voxnero.synth.views import render_views


def lambert(n, v, l, albedo, metallic, roughness):
    """Pure Lambertian BRDF albedo/π (upper hemisphere only), same signature as brdf_eval."""
    up = ((n * v).sum(-1, keepdim=True) > 0) & ((n * l).sum(-1, keepdim=True) > 0)
    return torch.where(up, albedo / math.pi, torch.zeros_like(albedo))


def _samples(material: Material, env: EnvMap, res: int = 32, spp: int = 16, brdf=brdf_eval,
             seed: int = 0, max_depth: int = 2, with_mu: bool = False):
    """Per-sample radiance (P, spp, 3) of one view of a sphere, the samples' hit mask
    (P, spp) and (optionally) the cosine n·v (P, spp) at each primary hit."""
    cams = make_cameras(np.array([[0.3, -0.8, 0.52]]) / np.linalg.norm([0.3, -0.8, 0.52]), res)
    gen = torch.Generator().manual_seed(seed)
    pix = pixel_samples(res, res, spp, gen).reshape(-1, 2)
    pid = torch.arange(res * res).repeat_interleave(spp)
    o, d = pixel_rays(cams, torch.zeros(len(pix), dtype=torch.long), pix)
    geo = Union([Sphere((0.0, 0.0, 0.0), 0.8)])
    L, t, obj = trace_paths(geo, MaterialTable.from_materials([material]), env, o, d,
                            max_depth, gen, brdf)
    order = torch.argsort(pid, stable=True)
    out = (L[order].reshape(res * res, spp, 3), (obj[order] >= 0).reshape(res * res, spp))
    if with_mu:
        x = o + t.clamp_max(1e3)[:, None] * d
        mu = -(geo.normal(x, obj.clamp_min(0)) * d).sum(-1)
        out = out + (mu[order].reshape(res * res, spp),)
    return out


def _directional_albedo(mu: torch.Tensor, r: float, n_theta: int) -> torch.Tensor:
    """∫ brdf_eval(n, v, l) (n·l) dl over the hemisphere for white metal (F = 1), by midpoint
    quadrature in (θ, φ) at 33 values of n·v, linearly interpolated at ``mu``."""
    nodes = torch.linspace(0, 1, 33, dtype=torch.float64) ** 1.5
    th = (torch.arange(n_theta, dtype=torch.float64) + 0.5) / n_theta * math.pi / 2
    ph = (torch.arange(2 * n_theta, dtype=torch.float64) + 0.5) / (2 * n_theta) * 2 * math.pi
    T, P = torch.meshgrid(th, ph, indexing="ij")
    l = torch.stack([T.sin() * P.cos(), T.sin() * P.sin(), T.cos()], -1).reshape(-1, 3)
    dw = (T.sin() * (math.pi / 2 / n_theta) * (math.pi / n_theta)).reshape(-1)
    one = torch.ones(len(l), 1, dtype=torch.float64)
    vals = []
    for m in nodes.clamp_min(1e-4).tolist():
        v = torch.tensor([math.sqrt(1 - m * m), 0.0, m], dtype=torch.float64).expand_as(l)
        n = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(l)
        f = brdf_eval(n, v, l, one.expand(-1, 3), one, one * r)[:, 0]
        vals.append((f * l[:, 2] * dw).sum())
    vals = torch.stack(vals)
    k = torch.searchsorted(nodes, mu.double().clamp(0, 1).contiguous()).clamp(1, 32)
    w = (mu.double() - nodes[k - 1]) / (nodes[k] - nodes[k - 1])
    return vals[k - 1] * (1 - w) + vals[k] * w


@pytest.mark.parametrize("E", [1.0, 0.37])
def test_white_furnace_lambert_returns_the_environment(E):
    env = EnvMap(torch.as_tensor(constant_envmap(16, E)))
    L, hit = _samples(Material((1.0, 1.0, 1.0), 0.0, 1.0), env, spp=64, brdf=lambert)
    obj = hit.all(1)  # fully covered pixels (partly covered ones mix with E as well)
    assert obj.sum() > 150
    s1 = L[obj].std().item()  # per-sample σ₁, pooled
    spp = L.shape[1]
    pix_mean = L.mean(1)
    assert (pix_mean[obj] - E).abs().max() <= 5 * s1 / math.sqrt(spp) + 1e-6
    n = obj.sum().item() * spp
    assert abs(pix_mean[obj].mean().item() - E) <= 5 * s1 / math.sqrt(n) + 1e-6
    assert s1 < 0.5 * E  # MIS keeps the estimator's noise moderate
    assert torch.allclose(pix_mean[~hit.any(1)], torch.full((1,), E))  # background = env


@pytest.mark.parametrize("r, n_theta", [(0.3, 120), (1.0, 60)])
def test_white_furnace_ggx_never_creates_energy(r, n_theta):
    """White metal (pure GGX lobe, F = 1) under constant E: ≤ E everywhere, and equal to the
    lobe's directional albedo A(n·v)·E from an independent quadrature of brdf_eval."""
    E = 1.0
    env = EnvMap(torch.as_tensor(constant_envmap(16, E)))
    spp = 64
    L, hit, mu = _samples(Material((1.0, 1.0, 1.0), 1.0, r), env, spp=spp, with_mu=True)
    obj = hit.all(1)
    s1 = L[obj].std().item()
    pix_mean = L.mean(1)[obj]
    assert (pix_mean <= E + 5 * s1 / math.sqrt(spp)).all()
    expected = E * _directional_albedo(mu[obj], r, n_theta).mean().item()
    mean = pix_mean.mean().item()
    n = obj.sum().item() * spp
    assert abs(mean - expected) <= 5 * s1 / math.sqrt(n) + 3e-3  # + quadrature error
    assert mean < E  # single-scattering GGX loses energy (most at high roughness)


def test_dielectric_white_reflects_what_it_receives():
    """The project's dielectric BRDF gives its diffuse lobe the energy the specular interface
    does not reflect (render/brdf.py): a white dielectric under E returns E, not E·(1 + E_spec)
    as an unweighted diffuse lobe would (1.04–1.2·E here)."""
    env = EnvMap(torch.as_tensor(constant_envmap(16, 1.0)))
    L, hit = _samples(Material((1.0, 1.0, 1.0), 0.0, 0.5), env, spp=16)
    m = L.mean(1)[hit.all(1)].mean().item()
    assert abs(m - 1.0) < 0.015


def _dot_env(dirs: list[np.ndarray], H: int = 128, sigma_deg: float = 0.8) -> torch.Tensor:
    """Dark env with one bright Gaussian dot per direction, in channel k for dot k."""
    pd = pixel_dirs(H, 2 * H).double()
    img = torch.full((H, 2 * H, 3), 1e-3, dtype=torch.float64)
    for k, w in enumerate(dirs):
        ang = torch.arccos((pd @ torch.as_tensor(w)).clamp(-1, 1))
        img[..., k] += 50.0 * torch.exp(-0.5 * (ang / math.radians(sigma_deg)) ** 2)
    return img.float()


def _mirror_point(eye: np.ndarray, w: np.ndarray, r: float) -> np.ndarray:
    """Point on the origin-centred sphere where the view from ``eye`` reflects toward w."""
    n = (w + eye / np.linalg.norm(eye))
    n /= np.linalg.norm(n)
    for _ in range(100):
        p = r * n
        v = (eye - p) / np.linalg.norm(eye - p)
        n = (v + w) / np.linalg.norm(v + w)
    return r * n


def test_mirror_sphere_reflects_dots_where_the_reflection_law_says():
    dirs = [np.array(v, dtype=np.float64) / np.linalg.norm(v)
            for v in ([0.2, -1.0, 0.5], [-0.9, -0.4, -0.1], [0.8, -0.5, 0.9])]
    env = EnvMap(_dot_env(dirs))
    res = 128
    view = np.array([0.25, -0.9, 0.35])
    view /= np.linalg.norm(view)
    cams = make_cameras(view[None], res)
    geo = Union([Sphere((0.0, 0.0, 0.0), 0.8)])
    mat = MaterialTable.from_materials([Material((1.0, 1.0, 1.0), 1.0, 0.0)])
    img, _ = render_views(geo, mat, env, cams, [0], spp=4, max_depth=1,
                          generator=torch.Generator().manual_seed(0))
    img = img[0]
    w2c = torch.linalg.inv(cams.c2w[0].double())
    K = cams.K[0].double()
    for k, w in enumerate(dirs):
        p = _mirror_point(4.0 * view, w, 0.8)
        pc = w2c[:3, :3] @ torch.as_tensor(p) + w2c[:3, 3]
        uv = (K @ (pc / pc[2]))[:2]  # continuous pixel coordinates (x = col, y = row)
        ch = img[..., k]
        j, i = np.unravel_index(int(ch.argmax()), ch.shape)
        # brightness-weighted centroid of the 7x7 window around the brightest pixel
        win = ch[max(j - 3, 0):j + 4, max(i - 3, 0):i + 4]
        jj, ii = torch.meshgrid(torch.arange(max(j - 3, 0), max(j - 3, 0) + win.shape[0]),
                                torch.arange(max(i - 3, 0), max(i - 3, 0) + win.shape[1]),
                                indexing="ij")
        wsum = win.sum()
        centroid = torch.stack([(win * (ii + 0.5)).sum() / wsum, (win * (jj + 0.5)).sum() / wsum])
        assert (centroid.double() - uv).norm() < 1.0, (k, centroid, uv)
        assert ch.max() > 0.1  # the dot is really there


def test_two_spheres_reflection_needs_a_second_bounce():
    from voxnero.synth.config import SynthConfig
    from voxnero.synth.scenes import build_scene

    geo, mats, _ = build_scene("two_spheres", SynthConfig())
    table = MaterialTable.from_materials(mats)
    env = EnvMap(torch.as_tensor(constant_envmap(16, 1.0)))
    res = 96
    view = np.array([0.8, -1.0, 0.6])  # sees the side of A that mirrors B
    cams = make_cameras(view[None] / np.linalg.norm(view), res)
    imgs = {}
    for depth in (1, 2):
        imgs[depth], _ = render_views(geo, table, env, cams, [0], spp=16, max_depth=depth,
                                      generator=torch.Generator().manual_seed(1))
    diff = (imgs[2][0] - imgs[1][0]).abs().mean(-1)

    # where does the mirror reflection of each pixel centre of sphere A hit sphere B?
    jj, ii = torch.meshgrid(torch.arange(res), torch.arange(res), indexing="ij")
    pix = torch.stack([ii, jj], -1).reshape(-1, 2).float() + 0.5
    o, d = pixel_rays(cams, torch.zeros(len(pix), dtype=torch.long), pix)
    t, hit, obj = geo.intersect(o, d)
    on_a = (obj == 0)
    x = o + t.clamp_max(1e3)[:, None] * d
    n = geo.normal(x, obj.clamp_min(0))
    r = d - 2 * (d * n).sum(-1, keepdim=True) * n
    _, hit2, obj2 = geo.intersect(x + 1e-4 * n, r)
    sees_b = (on_a & hit2 & (obj2 == 1)).reshape(res, res)
    sees_env = (on_a & ~hit2).reshape(res, res)

    def erode(m):
        m = m.clone()
        m[1:-1, 1:-1] &= m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
        return m

    sees_b, sees_env = erode(sees_b), erode(sees_env)
    assert sees_b.sum() >= 10 and sees_env.sum() >= 100
    # on A, the second bounce matters only where the reflection hits B
    assert diff[sees_b].mean() > 0.1
    assert diff[sees_env].mean() < 0.02 * diff[sees_b].mean()
    # with one bounce A mirrors B as black (B does not emit); with two it shows lit B
    assert imgs[1][0][sees_b].mean() < 0.1 * imgs[2][0][sees_b].mean()
