"""One more start for the race: the carved start, hollow and opened where its run fits worst.

The coarse stage fills a cavity (a mug's, a bowl's): the photos see into it but never through
it to the background, so the density is opaque from the rim down, and the SDF stage, which
only moves its surface where it is, keeps the lid and paints the cavity's inside on it
(docs/STAGE1.md findings 41-43). Started from the true surface, `standard` holds the cavity
open and fits the photos better than the lid (finding 42). What is missing is a start that
proposes it, and the finished carved run points at it: the lid is where it explains the photos
worst (mug_glaze: per-pixel error 0.049 on the lid against 0.026 on the true surface; the
bowl 0.087 against 0.031; finding 44). So:

1. :func:`surface_error`: render the carved run's training views (every ``downscale``-th pixel
   block), cast the same rays on its mesh and average the error per cube of space on its
   surface;
2. :func:`worst_patch`: the largest connected set of those cubes whose error, blurred over
   the neighbours, exceeds ``k`` times the surface's median;
3. :func:`opened_shell`: the signed distance to the carved run's *finished* surface
   (:func:`outer_distance`) made a shell of thickness ``2τ`` (``|h + τ| − τ``) and cut away
   within ``ρ`` of the patch, as the next run's start (:func:`open_start`), whose SDF is held
   still while its appearance forms. Not the coarse hull's, the carved start itself: its
   voxel-scale roughness holes a thin shell (the mug's hollowed hull had genus 16, the bowl's
   37; the finished run's 10 and 0 after the same cut), and the mug's run from it ended with a
   tunnel too many in one run of two (finding 45).

A solid object also has a worst patch (the gear's tooth edges). Opened, it fits worse and the
race keeps the carved start, at the cost of one more complete run; so
:func:`material_contrast` first asks whether the patch is painted unlike the surface around it:
a lid is (to explain the cavity it hides), an edge is not, and only a lid is proposed
(finding 46). What is proposed is judged by the photos, as every start is.
Unit frame throughout; a pixel's error is the one the training steers its sampling by
(:func:`voxnero.shape.losses.pixel_error`, in ``loss.color_space``: sRGB-encoded by default).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    from voxnero.shape.trainer import ShapeTrainer

BLUR_BINS = 1.0
"""Gaussian sigma (in bins) of the error blurred over neighbouring surface bins."""
MIN_PIXELS = 20
"""Pixels a surface bin needs to count (fewer: its mean error is noise)."""
RING_BINS = 2.0
"""Width (in bins) of the ring of surface bins around the worst patch that
:func:`material_contrast` compares it with."""


def surface_error(tr: ShapeTrainer, bin_size: float, downscale: int = 2,
                  chunk: int = 8192) -> tuple[np.ndarray, np.ndarray]:
    """The fit of ``tr``'s model over its own surface.

    Every training view is rendered at the centres of ``downscale × downscale`` pixel blocks
    (the photos area-averaged to match) and the same rays are cast on the model's mesh; each
    hit adds its pixel's error (:func:`voxnero.shape.losses.pixel_error`) to the cube of side
    ``bin_size`` that holds it.

    Returns:
        ``points (M, 3)``: the mean hit point of each cube with at least :data:`MIN_PIXELS`
        hits (unit frame); ``error (M,)``: their mean per-pixel error.
    """
    from voxnero.cameras.rays import image_rays
    from voxnero.eval.views import MeshCaster
    from voxnero.shape import losses, schedules
    from voxnero.shape.renderer import as_photographed, render_rays

    caster = MeshCaster(tr.extract())
    ds = max(1, int(downscale))
    h, w = tr.h // ds, tr.w // ds
    photos = tr.images.view(tr.n_img, tr.h, tr.w, 3)[:, :h * ds, :w * ds]
    photos = photos.reshape(tr.n_img, h, ds, w, ds, 3).mean((2, 4))
    s = schedules.sharpness(tr.cfg, tr.step)
    nc = schedules.coarse_samples(tr.cfg, tr.step)
    keys, errs, pts = [], [], []
    tr.model.env.prepare()
    with torch.no_grad():
        for c in range(tr.n_img):
            o, d = image_rays(tr.cams, c, ds)
            o, d = o.reshape(-1, 3), d.reshape(-1, 3)
            o_np, d_np = o.cpu().numpy(), d.cpu().numpy()
            hit = caster.cast(o_np, d_np)["t"]
            sel = np.flatnonzero(np.isfinite(hit))
            if sel.size == 0:
                continue
            idx = torch.from_numpy(sel).to(o.device)
            rgb = torch.cat([render_rays(tr.model, o[idx[i:i + chunk]], d[idx[i:i + chunk]], s,
                                         tr.cfg, train=False, coarse=nc)["rgb"]
                             for i in range(0, idx.numel(), chunk)])
            rgb = as_photographed(tr.model, rgb, torch.full_like(idx, c))
            target = photos[c].reshape(-1, 3)[idx]
            err = losses.pixel_error(rgb, target, tr.cfg.loss.color_space).cpu().numpy()
            p = o_np[sel] + hit[sel, None] * d_np[sel]
            keys.append(np.floor(p / bin_size).astype(np.int64))
            errs.append(err)
            pts.append(p)
    tr.model.env.release()
    if not keys:
        return np.zeros((0, 3)), np.zeros(0)
    key, err, p = np.concatenate(keys), np.concatenate(errs), np.concatenate(pts)
    _, inv, count = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    mean_err = np.bincount(inv, err) / count
    mean_p = np.stack([np.bincount(inv, p[:, k]) for k in range(3)], 1) / count[:, None]
    keep = count >= MIN_PIXELS
    return mean_p[keep], mean_err[keep]


def worst_patch(points: np.ndarray, error: np.ndarray, bin_size: float, k: float
                ) -> np.ndarray:
    """The largest connected (26-neighbourhood of cubes of side ``bin_size``) set of surface
    points whose error, blurred over the neighbouring points (sigma :data:`BLUR_BINS` cubes),
    exceeds ``k`` times the median of the blurred errors; ``(P, 3)``, empty if none.

    Args:
        points: ``(M, 3)`` surface points, one per cube (:func:`surface_error`).
        error: ``(M,)`` their errors.
    """
    from scipy import ndimage

    if points.shape[0] == 0:
        return points
    ijk = np.floor(points / bin_size).astype(np.int64)
    ijk -= ijk.min(0) - 2
    shape = tuple(ijk.max(0) + 3)
    e, wgt = np.zeros(shape), np.zeros(shape)
    e[tuple(ijk.T)] = error
    wgt[tuple(ijk.T)] = 1.0
    blurred = ndimage.gaussian_filter(e, BLUR_BINS) / np.maximum(
        ndimage.gaussian_filter(wgt, BLUR_BINS), 1e-12)
    b = blurred[tuple(ijk.T)]
    high = b > k * np.median(b)
    mask = np.zeros(shape, bool)
    mask[tuple(ijk[high].T)] = True
    label, n = ndimage.label(mask, np.ones((3, 3, 3), bool))
    if n == 0:
        return points[:0]
    sizes = np.bincount(label.ravel())[1:]
    return points[label[tuple(ijk.T)] == int(np.argmax(sizes)) + 1]


def material_contrast(tr: ShapeTrainer, points: np.ndarray, patch: np.ndarray,
                      bin_size: float) -> dict:
    """How much the model's material on the worst patch differs from the surface around it.

    A lid is no surface of the object: to explain the cavity it hides (the inside's shadow, its
    reflections of itself) the model paints it with another material than the walls it joins
    (mug_glaze's lid metallic 0.51 against 0.01 on the glaze around it, bowl_silver's 0.20
    against 0.85), where a real surface that fits worst (a gear's tooth edges) has the material
    of its surroundings (docs/STAGE1.md finding 46).

    Args:
        points: ``(M, 3)`` surface points, one per cube (:func:`surface_error`), unit frame.
        patch: ``(P, 3)`` the subset of ``points`` that :func:`worst_patch` returned.
        bin_size: side of the cubes.

    Returns:
        ``{"patch": [...], "ring": [...], "contrast": c}``: mean (metallic, roughness, albedo
        r, g, b) of the patch's points and of the ring (points not in the patch within
        :data:`RING_BINS` cubes of it; albedo linear), and ``c`` the largest absolute
        difference of the five (0 if either set is empty).
    """
    from scipy.spatial import cKDTree

    if points.shape[0] == 0 or patch.shape[0] == 0:
        return {"patch": None, "ring": None, "contrast": 0.0}
    dist = cKDTree(patch).query(points)[0]
    inside = dist < 1e-6 * bin_size
    ring = ~inside & (dist <= RING_BINS * bin_size * (1 + 1e-6))
    if not inside.any() or not ring.any():
        return {"patch": None, "ring": None, "contrast": 0.0}
    used = inside | ring  # the material heads run on these points only
    x = torch.from_numpy(points[used]).to(tr.model.sdf.grid)
    with torch.no_grad():
        albedo, metallic, rough = tr.model.material(tr.model.feat(x))
    mat = torch.cat([metallic.reshape(-1, 1), rough.reshape(-1, 1), albedo], 1).cpu().numpy()
    a, b = mat[inside[used]].mean(0), mat[ring[used]].mean(0)
    return {"patch": [round(float(v), 3) for v in a], "ring": [round(float(v), 3) for v in b],
            "contrast": round(float(np.abs(a - b).max()), 4)}


def opened_shell(sdf: torch.Tensor, corners: torch.Tensor, patch: np.ndarray, tau: float,
                 rho: float) -> torch.Tensor:
    """The start ``max(|h + τ| − τ, ρ − dist(x, patch))``: the solid of ``h`` < 0 hollowed to
    a shell of thickness ``2τ`` and cut away within ``ρ`` of the patch points (a lower bound of
    the distance to the result, as an intersection of two such fields).

    Args:
        sdf: ``(1, D, H, W)`` signed distance ``h`` (negative inside) at ``corners``.
        corners: ``(D, H, W, 3)`` their positions (unit frame, last axis x, y, z).
        patch: ``(P, 3)`` points of the surface to open (empty: only hollowed).
        tau, rho: half the wall thickness and the radius cut around the patch (unit frame).

    Returns:
        ``(1, D, H, W)`` the new signed distance, ``sdf``'s dtype and device.
    """
    from scipy.spatial import cKDTree

    shell = (sdf + tau).abs() - tau
    if patch.shape[0] == 0:
        return shell
    far = float(rho) + 1.0
    dist, _ = cKDTree(patch).query(corners.reshape(-1, 3).cpu().numpy(),
                                   distance_upper_bound=far)
    dist = torch.from_numpy(np.minimum(dist, far)).to(sdf).view(sdf.shape)
    return torch.maximum(shell, rho - dist)


@torch.no_grad()
def closed_surface(tr: ShapeTrainer):
    """The largest component of ``tr``'s surface, closed: marching cubes of its SDF grid
    clipped to the sampling sphere and padded with one empty voxel on every face, so that a
    solid touching the grid's faces is closed there (:func:`outer_distance` takes its sign
    from ray parity, which an open surface would scramble). An Open3D mesh, unit frame."""
    import torch.nn.functional as F

    from voxnero.mesh.cleanup import clean_mesh
    from voxnero.mesh.extract import extract_mesh
    from voxnero.shape.run_files import clip_to_sphere

    sdf = tr.model.sdf
    b = sdf.bounds.detach().cpu().float()
    g = clip_to_sphere(sdf.grid.detach().cpu().float(), b, tr.cfg.sampling.radius)
    n = torch.tensor(g.shape[-3:][::-1], dtype=torch.float32)  # samples along x, y, z
    step = (b[1] - b[0]) / (n - 1)
    g = F.pad(g, (1,) * 6, value=float(step.max()))
    return clean_mesh(extract_mesh(g[0], torch.stack([b[0] - step, b[1] + step])))


def outer_distance(mesh, points: torch.Tensor) -> torch.Tensor:
    """Signed distance from ``points`` to a closed triangle mesh (negative inside), by Open3D's
    ray casting: the nearest point of the mesh for the distance, the parity of 7 rays'
    crossings for the sign (one ray that grazes an edge does not flip it).

    The opened start hollows this, not the carved run's own field: under a lid the field is no
    distance (on the bowl it rises to −0.0007 near the true floor's height, so ``|h + τ| − τ``
    left a wall 0.45 thick there, docs/STAGE1.md finding 47).

    Args:
        mesh: Open3D legacy ``TriangleMesh``, closed, same frame as ``points``.
        points: ``(..., 3)`` query points (any float dtype and device).

    Returns:
        ``(...)`` float32 distances on ``points``' device.
    """
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    q = o3d.core.Tensor(points.detach().reshape(-1, 3).cpu().float().numpy())
    d = scene.compute_signed_distance(q, nsamples=7).numpy()
    return torch.from_numpy(d).reshape(points.shape[:-1]).to(points.device)


def open_start(patch: np.ndarray, shell_voxels: float, hold: float, source):
    """An edit of a trainer's carved start (``ShapeTrainer.start_edit``): its SDF grid, just
    set from the coarse hull, becomes :func:`opened_shell` of the finished carved run's surface
    ``source`` (its :func:`outer_distance` at the grid's corners) with τ = ``shell_voxels``
    coarse voxels and ρ = 2τ plus one voxel of the SDF grid (the membrane left at the patch
    lies within 2τ of it), and the SDF is held still for the first ``hold`` of the run (its
    learning rate 0: the colour features, material and light form around the open shape before
    it may move; without it the bowl's rim grows a membrane by step 300). The decision "open"
    records both; the trainer reads the hold from it (:attr:`ShapeTrainer.sdf_hold`). The
    coarse stage before it still gives the run its env map and its box.

    Args:
        patch: ``(P, 3)`` points of the surface to open (unit frame).
        shell_voxels: τ in voxels of the coarse grid.
        hold: fraction of ``iters`` during which the SDF does not move.
        source: the finished carved run's surface (:func:`closed_surface`).
    """
    from voxnero.fields.grid import grid_points
    from voxnero.shape import adaptive, schedules

    def edit(tr: ShapeTrainer) -> None:
        g = tr.model.sdf
        cv = 2.0 * tr.cfg.grid.bound / (tr.cfg.coarse.res - 1)
        tau = shell_voxels * cv
        rho = 2.0 * tau + g.voxel
        start = g.grid.detach()
        corners = grid_points(start.shape[-1], g.bounds.cpu().float())
        h = outer_distance(source, corners).reshape(start.shape).to(start)
        n0 = int((h < 0).sum())
        f = opened_shell(h, corners, patch, tau, rho)
        n1 = int((f < 0).sum())
        steps = schedules.at(hold, tr.cfg)
        with torch.no_grad():
            g.grid.copy_(f)
        tr.decisions.append(adaptive.Decision(
            "open", True, shell_voxels,
            f"the carved run's surface hollowed to walls {2 * tau:.3f} thick and opened "
            f"within {rho:.3f} of the {patch.shape[0]} surface cubes the carved run fitted worst "
            f"({n0} -> {n1} grid corners inside); the SDF held for {steps} steps",
            {"patch_points": int(patch.shape[0]), "tau": round(tau, 5), "rho": round(rho, 5),
             "inside_before": n0, "inside_after": n1, "hold_steps": steps}, 0))

    return edit


def worst_patch_evidence(tr: ShapeTrainer, co) -> tuple[np.ndarray, dict]:
    """The finished run ``tr``'s :func:`worst_patch` (``(P, 3)``, unit frame) and the evidence
    on it: surface cubes, patch cubes, the median error, its :func:`material_contrast` with the
    ring around it, ``co.open_contrast``, ``co.open_gate`` and the seconds it took (``co``:
    the run's :class:`~voxnero.shape.config.CoarseConfig`, for ``res`` and ``open_k``)."""
    import time

    t0 = time.perf_counter()
    cv = 2.0 * tr.cfg.grid.bound / (co.res - 1)
    bin_size = 1.5 * cv
    points, error = surface_error(tr, bin_size)
    patch = worst_patch(points, error, bin_size, co.open_k)
    contrast = material_contrast(tr, points, patch, bin_size)
    seconds = time.perf_counter() - t0
    evidence = {"surface_cubes": int(points.shape[0]), "patch_cubes": int(patch.shape[0]),
                "median_error": round(float(np.median(error)), 5) if error.size else None,
                "k": co.open_k, "bin": round(bin_size, 5), "seconds": round(seconds, 2),
                "material": contrast, "min_contrast": co.open_contrast, "gate": co.open_gate}
    return patch, evidence


def propose_open(tr: ShapeTrainer, co) -> tuple:
    """The opened start from a finished carved run ``tr`` (``co``: its
    :class:`~voxnero.shape.config.CoarseConfig`): the :func:`open_start` edit of its
    :func:`worst_patch`, or ``None`` if there is no patch or the model's material on it differs
    from its surroundings by less than ``co.open_gate`` (:func:`material_contrast`; 0 proposes
    every patch), and the evidence for the race's decision (:func:`worst_patch_evidence`)."""
    patch, evidence = worst_patch_evidence(tr, co)
    contrast = evidence["material"]
    tr.log(f"[shape] worst-fitted patch of the carved run: {patch.shape[0]} of "
           f"{evidence['surface_cubes']} surface cubes above {co.open_k:g} x the median error; "
           f"its material differs from the ring around it by {contrast['contrast']:.2f} "
           f"(metallic, roughness, albedo; a lid's is {co.open_contrast:g} or more) "
           f"({evidence['seconds']:.0f} s)")
    if patch.shape[0] == 0 or contrast["contrast"] < co.open_gate:
        return None, evidence
    return open_start(patch, co.open_shell, co.open_hold, closed_surface(tr)), evidence
