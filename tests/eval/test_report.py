"""Tests of voxnero/eval/report.py: files written, values preserved, panels laid out."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from matplotlib import colormaps
from PIL import Image

from voxnero.eval.report import BAR, CMAP, GAP, comparison_image, write_report


def test_write_report_files_and_values(tmp_path):
    rng = np.random.default_rng(0)
    gt = rng.uniform(size=(20, 30, 3))
    pred = gt.copy()
    pred[5:10, 5:10] += 0.3
    metrics = {"chamfer": {"cd": 0.0123, "acc": 0.01, "comp": 0.0146},
               "psnr": math.inf, "note": "x", "n": np.int64(5), "bad": float("nan")}
    paths = write_report(tmp_path / "out", metrics,
                         {"view0": (pred, gt), "rough": (torch.zeros(20, 30), np.ones((20, 30)))})
    data = json.loads(paths["json"].read_text())
    assert data["chamfer"] == metrics["chamfer"]
    assert data["psnr"] == "inf" and float(data["psnr"]) == math.inf
    assert data["n"] == 5 and data["bad"] == "nan"
    md = paths["md"].read_text()
    assert "| chamfer.cd | 0.0123 |" in md and "| psnr | inf |" in md and "view0.png" in md
    for name in ("view0", "rough"):
        img = np.asarray(Image.open(paths[name]))
        assert img.shape == (20, 3 * 30 + 3 * GAP + BAR, 3)


def test_panels_are_prediction_truth_and_error():
    gt = np.full((16, 16, 3), 0.5)
    pred = gt.copy()
    pred[:8] = 0.9  # error 0.4 on the top half, 0 below
    img, vmax = comparison_image(pred, gt)
    assert vmax == pytest.approx(0.4)
    w = 16
    assert (img[:, :w] == np.round(np.clip(pred, 0, 1) * 255)).all()
    assert (img[:, w + GAP:2 * w + GAP] == 128).all()
    heat = img[:, 2 * (w + GAP):3 * w + 2 * GAP]
    cmap = colormaps[CMAP]
    top = (np.array(cmap(1.0)[:3]) * 255).round()
    bottom = (np.array(cmap(0.0)[:3]) * 255).round()
    assert (heat[:8] == top).all() and (heat[8:] == bottom).all()
    assert (img[:, w:w + GAP] == 255).all()


def test_shape_errors():
    with pytest.raises(ValueError, match="differ in shape"):
        comparison_image(np.zeros((4, 4, 3)), np.zeros((4, 5, 3)))
    with pytest.raises(ValueError, match="report images"):
        comparison_image(np.zeros((4, 4, 2)), np.zeros((4, 4, 2)))
