"""``materials.json``: summary statistics of the recovered materials and light."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np


def weighted_stats(values: np.ndarray, weights: np.ndarray | None = None) -> dict[str, Any]:
    """Weighted mean, std, and (unweighted) 5/50/95 percentiles per channel.

    Args:
        values: (N,) or (N, C).
        weights: (N,) non-negative weights (default uniform).

    Returns:
        ``{"mean", "std", "p5", "median", "p95"}``, scalars for (N,) input, lists for (N, C).
    """
    v = np.asarray(values, dtype=np.float64)
    scalar = v.ndim == 1
    v = v.reshape(v.shape[0], -1)
    w = np.ones(v.shape[0]) if weights is None else np.asarray(weights, dtype=np.float64)
    w = w / max(w.sum(), 1e-30)
    mean = (w[:, None] * v).sum(0)
    std = np.sqrt((w[:, None] * (v - mean) ** 2).sum(0))
    p5, p50, p95 = np.percentile(v, [5, 50, 95], axis=0)

    def f(a):
        return float(a[0]) if scalar else [float(x) for x in a]

    return {"mean": f(mean), "std": f(std), "p5": f(p5), "median": f(p50), "p95": f(p95)}


def vertex_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area per vertex: a third of the area of every adjacent triangle. Returns (V,)."""
    p = vertices[triangles]
    a = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    out = np.zeros(vertices.shape[0])
    for k in range(3):
        np.add.at(out, triangles[:, k], a / 3)
    return out


def write_summary(path: str | Path, albedo: np.ndarray, metallic: np.ndarray,
                  roughness: np.ndarray, weights: np.ndarray | None, env: np.ndarray,
                  extra: dict[str, Any] | None = None) -> Path:
    """Write ``materials.json``.

    Args:
        path: output file.
        albedo: (N, 3) linear base colour samples (e.g. per vertex).
        metallic: (N,) metallic; roughness: (N,) perceptual roughness.
        weights: (N,) weights (e.g. vertex areas) or None.
        env: (H, W, 3) linear env map (mean / max radiance are reported).
        extra: anything else (decisions, timings, metrics).
    """
    doc = {"albedo_linear": weighted_stats(albedo, weights),
           "metallic": weighted_stats(np.asarray(metallic).reshape(-1), weights),
           "roughness_perceptual": weighted_stats(np.asarray(roughness).reshape(-1), weights),
           "roughness_note": "perceptual r; GGX alpha = r^2",
           "envmap": {"height": int(env.shape[0]), "width": int(env.shape[1]),
                      "mean_radiance": [float(x) for x in env.reshape(-1, 3).mean(0)],
                      "max_radiance": [float(x) for x in env.reshape(-1, 3).max(0)]}}
    doc.update(extra or {})
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1))
    return path
