"""materials.json statistics against direct numpy computations."""

from __future__ import annotations

import json

import numpy as np

from voxnero.material.summary import vertex_areas, weighted_stats, write_summary


def test_weighted_stats_and_areas(tmp_path):
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]])
    f = np.array([[0, 1, 2], [1, 3, 2]])
    w = vertex_areas(v, f)
    assert np.allclose(w, [1 / 6, 1 / 3, 1 / 3, 1 / 6]) and np.isclose(w.sum(), 1.0)
    vals = np.array([0.0, 1.0, 1.0, 0.0])
    s = weighted_stats(vals, w)
    assert np.isclose(s["mean"], 2 / 3) and np.isclose(s["std"], np.sqrt(2 / 9))
    rgb = np.stack([vals, 1 - vals, vals * 0.5], 1)
    s3 = weighted_stats(rgb)
    assert np.allclose(s3["mean"], rgb.mean(0)) and np.allclose(s3["median"],
                                                                np.median(rgb, 0))
    path = write_summary(tmp_path / "materials.json", rgb, vals, vals, w,
                         np.ones((4, 8, 3)), extra={"note": 1})
    doc = json.loads(path.read_text())
    assert np.isclose(doc["metallic"]["mean"], 2 / 3) and doc["note"] == 1
    assert doc["envmap"]["mean_radiance"] == [1.0, 1.0, 1.0]
