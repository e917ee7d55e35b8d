#!/usr/bin/env python
"""Diagnostic: a mask-free visual-hull cue from background consistency, scored on the corpus.

An environment at infinity gives one radiance per direction, whatever the view. So a training
pixel whose colour disagrees with the median over the views that see the same direction is
object. This script bins pixel directions on an equirectangular grid. It takes per (view, bin)
the mean sRGB colour and per bin the median over views, and calls a pixel "object" where
``max |colour - median| > tau``. It then scores that mask against the scene's true train masks
(coverage > 0.5; evaluation only). It measures a prior for stage 1 (docs/STAGE1.md, finding
16) and is not part of the method.

Example::

    python -m tools.corpus.bg_consistency cache/corpus/table_oak cache/corpus/knot_chrome
"""

from __future__ import annotations

import argparse
import json
import math
import warnings
from pathlib import Path

import numpy as np

from tools.corpus.rigs import pixel_directions


def object_mask(images: np.ndarray, dirs: np.ndarray, bins_w: int = 512, tau: float = 0.06
                ) -> np.ndarray:
    """``(V, H, W)`` bool "object" from ``images (V, H, W, 3)`` in sRGB [0, 1] and their pixel
    directions ``dirs (V, H, W, 3)`` (env-map convention of ../shared/data: ``u = atan2(dx,
    dy) / 2pi``, ``v = arccos(dz) / pi``)."""
    v_count, h, w = images.shape[:3]
    bins_h = bins_w // 2
    u = (np.arctan2(dirs[..., 0], dirs[..., 1]) / (2 * math.pi)) % 1.0
    v = np.arccos(np.clip(dirs[..., 2], -1, 1)) / math.pi
    b = (np.minimum((v * bins_h).astype(int), bins_h - 1) * bins_w
         + np.minimum((u * bins_w).astype(int), bins_w - 1)).reshape(v_count, -1)
    col = images.reshape(v_count, -1, 3)
    nb = bins_w * bins_h
    means = np.full((v_count, nb, 3), np.nan)
    for k in range(v_count):
        cnt = np.bincount(b[k], minlength=nb)
        for c in range(3):
            s = np.bincount(b[k], weights=col[k, :, c], minlength=nb)
            means[k, :, c] = np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # bins no view sees: NaN, unused
        env = np.nanmedian(means, axis=0)
    res = np.abs(col - env[b]).max(-1).reshape(v_count, h, w)
    return res > tau


def score(scene: Path, tau: float = 0.06) -> dict:
    """IoU, precision and recall of :func:`object_mask` against the true train masks."""
    from PIL import Image

    doc = json.loads((scene / "transforms_train.json").read_text())
    f, w, h = float(doc["fl_x"]), int(doc["w"]), int(doc["h"])
    ims, gts, dirs = [], [], []
    for fr in doc["frames"]:
        ims.append(np.asarray(Image.open(scene / f"{fr['file_path']}.png"))[..., :3] / 255.0)
        mpath = scene / f"{fr['file_path'].replace('/train/', '/train_mask/')}.png"
        gts.append(np.asarray(Image.open(mpath)) / 255.0 > 0.5)
        dirs.append(pixel_directions(np.array(fr["transform_matrix"]), f, w, h))
    pred, gt = object_mask(np.stack(ims), np.stack(dirs), tau=tau), np.stack(gts)
    inter = float((pred & gt).sum())
    return {"scene": scene.name, "iou": inter / float((pred | gt).sum()),
            "precision": inter / max(float(pred.sum()), 1.0), "recall": inter / float(gt.sum())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenes", nargs="+", type=Path, help="corpus scene folders (with masks)")
    ap.add_argument("--tau", type=float, default=0.06, help="sRGB difference called object")
    args = ap.parse_args(argv)
    for s in args.scenes:
        r = score(s, args.tau)
        print(f"{r['scene']:20s} IoU {r['iou']:.3f}  precision {r['precision']:.3f}  "
              f"recall {r['recall']:.3f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
