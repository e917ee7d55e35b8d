"""Which evaluation a target gets, and its summary lines (``voxnero eval`` is argument parsing
plus :func:`evaluate_target`).

* a scene with ground-truth depth at its test views (dev scenes, ``voxnero synth``): Chamfer and
  normal error, plus image / material metrics for a stage-2 run (:mod:`voxnero.eval.ground_truth`);
* a capture with object masks but no ground truth (DTU in the NeuS/IDR layout): cull by the
  training masks, silhouette IoU / precision / recall at the held-out views, plus PSNR inside the
  masks for a stage-2 run (:mod:`voxnero.eval.capture`).
"""

from __future__ import annotations

from pathlib import Path


def has_ground_truth(scene_path: Path, split: str) -> bool:
    """Whether the scene has GT depth for ``split`` (else the capture protocol applies)."""
    from voxnero.data.detect import detect_format

    root = Path(scene_path)
    fmt = detect_format(root)
    if fmt == "blender":
        return (root / "gt" / f"{split}_depth").is_dir()
    if fmt == "nero":
        return any(root.glob("*-depth.png"))
    return False


def evaluate_target(target: str | Path, scene: str | None, cfg, out: Path) -> dict:
    """Find the mesh and the scene of ``target`` and score it by the protocol that applies.

    Args:
        target: run folder (stage 1 or 2) or mesh file, in the scene's input frame.
        scene: ``--scene`` (None: the run's own scene from its ``config.yaml``).
        cfg: :class:`voxnero.eval.config.EvalConfig`.
        out: report folder.

    Returns:
        The metrics dict (also written as ``metrics.json``/``.md`` in ``out``).
    """
    from voxnero.eval.capture import evaluate_capture
    from voxnero.eval.ground_truth import evaluate
    from voxnero.eval.targets import find_mesh, find_scene, is_stage2_run

    mesh_path = find_mesh(target)
    scene_path = find_scene(target, scene)
    stage2 = Path(target) if is_stage2_run(target) else None
    if has_ground_truth(scene_path, cfg.split):
        return evaluate(mesh_path, scene_path, cfg, out, stage2_run=stage2)
    return evaluate_capture(mesh_path, scene_path, cfg, out, stage2_run=stage2)


def summary_lines(m: dict) -> list[str]:
    """What ``voxnero eval`` prints for a metrics dict of either protocol."""
    lines = []
    if "silhouette" in m:
        s = m["silhouette"]
        lines.append(f"silhouette IoU {s['iou']:.4f} (precision {s['precision']:.4f}, recall "
                     f"{s['recall']:.4f}; {m['n_views']} held-out views, mesh culled by "
                     f"{m['n_train_views']} training masks)")
        im = m.get("images")
        if isinstance(im, dict):
            lines.append(f"held-out PSNR inside the masks {im['psnr_masked']:.2f} dB "
                         f"({len(im['views'])} views)")
    else:
        c = m["chamfer"]
        line = (f"chamfer {c['cd']:.5f} (acc {c['acc']:.5f}, comp {c['comp']:.5f}; "
                f"{m['n_views']} views, input frame)")
        if isinstance(m["normals"], dict):
            line += (f"; normal error mean {m['normals']['mean_deg']:.2f} deg, median "
                     f"{m['normals']['median_deg']:.2f} deg")
        lines.append(line)
        if isinstance(m.get("chamfer_exact"), dict):
            e = m["chamfer_exact"]
            lines.append(f"chamfer against the true mesh at the pixel centres {e['cd']:.5f} "
                         f"(acc {e['acc']:.5f}, comp {e['comp']:.5f}); the truth scores "
                         f"{e['truth_cd']:.5f} against the stored depth")
        if isinstance(m.get("novel_view"), dict):
            nv, mt = m["novel_view"], m["materials"]
            lines.append(f"novel views PSNR {nv['psnr']:.2f} dB (object {nv['psnr_object']:.2f} "
                         f"dB), SSIM {nv['ssim']:.3f}; albedo PSNR {mt['albedo_psnr']:.2f} dB, "
                         f"metallic MAE {mt['metallic_mae']:.3f}, roughness MAE "
                         f"{mt['roughness_mae']:.3f} ({len(m['views'])} views)")
            for env, v in m.get("relight", {}).items():
                lines.append(f"relight {env}: PSNR {v['psnr']:.2f} dB, SSIM {v['ssim']:.3f}")
    if "warning" in m:
        lines.append(f"warning: {m['warning']}")
    return lines
