"""Evaluation reports: ``metrics.json``, ``metrics.md`` and side-by-side comparison PNGs.

Each comparison image is one row of panels, separated by 4 white pixels:
``prediction | truth | error heat map | colour bar``. Prediction and truth are shown as given
(values clipped to [0, 1]; pass sRGB-encoded images, or normal maps as ``n · 0.5 + 0.5``); the
heat map is the per-pixel absolute error averaged over channels, mapped with matplotlib's
``magma`` colormap from 0 to ``vmax`` = the 99th percentile of the error (at least 1e-6), so a
few outliers do not wash it out; the colour bar runs from 0 (bottom) to ``vmax`` (top), and
``vmax`` is written in ``metrics.md``.

JSON cannot hold inf/NaN: such values are written as the strings ``"inf"``, ``"-inf"``,
``"nan"`` (``float(s)`` reads them back).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import torch
from matplotlib import colormaps
from PIL import Image

GAP = 4
"""White pixels between panels."""
BAR = 12
"""Width of the colour bar in pixels."""
CMAP = "magma"


def json_safe(x: Any) -> Any:
    """``x`` with tensors/arrays as lists, paths as strings and every non-finite float as the
    string ``"nan"``, ``"inf"`` or ``"-inf"``: writable with ``json.dumps(allow_nan=False)``, so
    no output file holds a bare NaN (which is not JSON)."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if isinstance(x, (np.generic, torch.Tensor)) and np.ndim(x) == 0:
        x = x.item()
    if isinstance(x, np.ndarray):
        return json_safe(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return "nan" if math.isnan(x) else ("inf" if x > 0 else "-inf")
    if isinstance(x, Path):
        return str(x)
    return x


def _flatten(d: dict, prefix: str = "") -> list[tuple[str, Any]]:
    rows = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            rows += _flatten(v, key + ".")
        else:
            rows.append((key, v))
    return rows


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.6g}"
    return str(v)


def _hwc(img: torch.Tensor | np.ndarray) -> np.ndarray:
    a = img.detach().cpu().numpy() if isinstance(img, torch.Tensor) else np.asarray(img)
    a = a.astype(np.float64)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[-1] not in (1, 3):
        raise ValueError(f"report images must be (H, W), (H, W, 1) or (H, W, 3), got {a.shape}")
    return a


def _rgb8(a: np.ndarray) -> np.ndarray:
    if a.shape[-1] == 1:
        a = np.repeat(a, 3, -1)
    return np.round(np.clip(a, 0, 1) * 255).astype(np.uint8)


def comparison_image(pred: torch.Tensor | np.ndarray, gt: torch.Tensor | np.ndarray
                     ) -> tuple[np.ndarray, float]:
    """Compose ``prediction | truth | error heat map | colour bar`` (module docstring).

    Args:
        pred, gt: ``(H, W)``, ``(H, W, 1)`` or ``(H, W, 3)`` images, display values in [0, 1].

    Returns:
        ``(H, 3W + BAR + 3·GAP, 3)`` uint8 image and the heat map's ``vmax``.
    """
    p, g = _hwc(pred), _hwc(gt)
    if p.shape != g.shape:
        raise ValueError(f"pred {p.shape} and gt {g.shape} differ in shape")
    h, w = p.shape[:2]
    err = np.abs(p - g).mean(-1)
    vmax = max(float(np.percentile(err, 99)), 1e-6)
    cmap = colormaps[CMAP]
    heat = (cmap(np.clip(err / vmax, 0, 1))[..., :3] * 255).round().astype(np.uint8)
    bar_vals = np.linspace(1, 0, h)[:, None].repeat(BAR, 1)
    bar = (cmap(bar_vals)[..., :3] * 255).round().astype(np.uint8)
    gap = np.full((h, GAP, 3), 255, np.uint8)
    return np.concatenate([_rgb8(p), gap, _rgb8(g), gap, heat, gap, bar], 1), vmax


def write_report(out_dir: str | Path, metrics: dict[str, Any],
                 images: dict[str, tuple[Any, Any]] | None = None,
                 title: str = "VoxNeRO evaluation") -> dict[str, Path]:
    """Write ``metrics.json``, ``metrics.md`` and one ``<name>.png`` comparison per image pair.

    Args:
        out_dir: output folder (created).
        metrics: nested dict of numbers/strings (nested keys become ``a.b`` rows in Markdown).
        images: ``{name: (prediction, truth)}`` display images (see :func:`comparison_image`).
        title: heading of ``metrics.md``.

    Returns:
        ``{"json": path, "md": path, <name>: png path, ...}``.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    vmaxes: dict[str, float] = {}
    for name, (pred, gt) in (images or {}).items():
        img, vmaxes[name] = comparison_image(pred, gt)
        paths[name] = out / f"{name}.png"
        Image.fromarray(img).save(paths[name])
    paths["json"] = out / "metrics.json"
    paths["json"].write_text(json.dumps(json_safe(metrics), indent=2, allow_nan=False) + "\n")
    lines = [f"# {title}", "", "| metric | value |", "|---|---|"]
    lines += [f"| {k} | {_fmt(v)} |" for k, v in _flatten(metrics)]
    if vmaxes:
        lines += ["", "## Comparisons", "",
                  "prediction | truth | abs. error (channel mean, magma colormap, 0 → vmax)", ""]
        lines += [f"- `{name}.png` (error vmax {v:.4g})" for name, v in vmaxes.items()]
    paths["md"] = out / "metrics.md"
    paths["md"].write_text("\n".join(lines) + "\n")
    return paths
