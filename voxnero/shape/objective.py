"""The stage-1 training objective: the loss terms of :mod:`voxnero.shape.losses`, weighted by
``loss.*`` and switched on by :mod:`voxnero.shape.schedules`.

``L = colour + eikonal·E + laplacian·Δ² + normal_smooth·N + occlusion·O``: the Charbonnier
photometric term, the eikonal term on the sample gradients, the squared Laplacian of the SDF grid,
the normal smoothness between surface points and points jittered by ``loss.normal_smooth_radius``
voxels of the first grid, and the occlusion net's fit to ray-cast targets
(:class:`voxnero.shape.occlusion.OcclusionTargets`, rebuilt every ``loss.occlusion_every``
steps). A new stage-1 loss is a function in :mod:`voxnero.shape.losses`, a weight in
:class:`voxnero.shape.config.LossConfig` and a term here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch

from voxnero.shape import light_switch, losses, schedules

if TYPE_CHECKING:
    from voxnero.shape.trainer import ShapeTrainer


def objective(tr: ShapeTrainer, out: dict[str, torch.Tensor], target: torch.Tensor
              ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """The loss of one training batch at ``tr.step``.

    Args:
        tr: the trainer (config, model, batch RNG ``gen`` for the jitter, occlusion targets,
            which are rebuilt here when due).
        out: :func:`voxnero.shape.renderer.render_rays` output of the batch (``train=True``).
        target: ``(R, 3)`` the photos' linear RGB.

    Returns:
        ``(loss, terms)``: the weighted sum (a scalar tensor) and the unweighted terms
        ``color``, ``eik``, ``occ``, ``nsmooth``.
    """
    cfg, m, step, lc = tr.cfg, tr.model, tr.step, tr.cfg.loss
    l_col = losses.color_loss(out["rgb"], target, lc.charbonnier_eps, lc.color_space)
    l_eik = losses.eikonal(out["grad"])
    l_lap = losses.laplacian(m.sdf.grid[0], m.sdf.voxel) if lc.laplacian > 0 else 0.0
    loss = l_col + lc.eikonal * l_eik + lc.laplacian * l_lap
    l_ns = torch.zeros(())
    if schedules.normal_smooth_on(cfg, step) and "x" in out:
        x = out["x"][out["acc_hit"] > 0.5]
        jit = torch.randn(x.shape, generator=tr.gen, device=x.device)
        xj = x + jit * (lc.normal_smooth_radius * tr.coarse_voxel)
        _, g2 = m.sdf.sdf_grad(torch.cat([x, xj]), cfg.grid.normals, cfg.grid.fd_step)
        g2 = torch.nn.functional.normalize(g2, dim=-1)
        l_ns = losses.normal_smoothness(g2[:x.shape[0]], g2[x.shape[0]:])
        loss = loss + lc.normal_smooth * l_ns
    l_occ = torch.zeros(())
    if "occ" in out and schedules.occlusion_loss_on(cfg, step):
        if tr.occ_targets is None or schedules.occlusion_targets_due(cfg, step):
            tr.occ_targets = light_switch.occlusion_targets(tr)
        if tr.occ_targets is not None:
            keep = out["acc_hit"] > 0.5
            tgt, valid = tr.occ_targets.test(out["x"][keep], out["n_hit"][keep],
                                             out["refl"][keep])
            if bool(valid.any()):  # only reflected rays that leave the surface (d·n > 0)
                l_occ = losses.occlusion_loss(out["occ"][keep][valid], tgt[valid])
                loss = loss + lc.occlusion * l_occ
    return loss, {"color": l_col, "eik": l_eik, "occ": l_occ, "nsmooth": l_ns}
