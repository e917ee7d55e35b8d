"""NeuS/IDR-layout loader (DTU) on a code-built capture: projections, pixel convention, region
of interest, the index % 8 hold-out, masks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.fixtures.scenes import IDR_SCALE, SPHERE_C, check_rays_hit_sphere, make_idr
from voxnero.data.detect import available_splits, detect_format, load_scene
from voxnero.data.idr import decompose_projection, load_idr
from voxnero.errors import DataError


def test_rays_reproduce_rendered_sphere_both_splits(tmp_path):
    b = make_idr(tmp_path)
    assert detect_format(tmp_path) == "idr"
    assert available_splits(tmp_path) == ["train", "test", "all"]
    sc = load_scene(tmp_path, splits=("train", "test"))
    assert sc.format == "idr"
    assert sc.split("test").names == ["000", "008"]
    assert sc.split("train").names == [f"{k:03d}" for k in range(10) if k % 8]
    for s in ("train", "test"):
        # the loader's cameras (OpenCV, centres at +0.5) reproduce a render through P with
        # integer pixel centres
        check_rays_hit_sphere(sc.split(s), sc.norm, b.hits[s], b.margins[s])


def test_region_of_interest_is_scale_mat_sphere(tmp_path):
    make_idr(tmp_path, n=3)
    sc = load_idr(tmp_path)
    np.testing.assert_allclose(sc.norm.center, IDR_SCALE[:3, 3])
    assert sc.norm.scale == pytest.approx(1.4)
    assert "scale_mat" in sc.meta["normalisation"]["method"]
    # the user's region of interest wins
    sc2 = load_idr(tmp_path, bbox=[-1, -1, -1, 1, 1, 3])
    np.testing.assert_allclose(sc2.norm.center, [0, 0, 1])
    assert sc2.norm.scale == pytest.approx(np.sqrt(4 + 4 + 16) / 2)


def test_decompose_projection_recovers_camera():
    rng = np.random.default_rng(0)
    from scipy.spatial.transform import Rotation

    R = Rotation.random(random_state=1).as_matrix()
    c = rng.normal(size=3)
    K = np.array([[500.0, 0.7, 200], [0, 480, 150], [0, 0, 1]])
    P = -3.2 * K @ np.concatenate([R, (-R @ c)[:, None]], 1)  # negative overall scale
    K2, c2w = decompose_projection(P)
    np.testing.assert_allclose(K2, K, atol=1e-8)
    np.testing.assert_allclose(c2w[:3, :3], R.T, atol=1e-10)
    np.testing.assert_allclose(c2w[:3, 3], c, atol=1e-10)


def test_masks_are_eval_data_or_alpha(tmp_path):
    b = make_idr(tmp_path)
    sc = load_idr(tmp_path, splits=("test",))
    assert sc.split("test").masks is None and sc.background == "unknown"
    sc = load_idr(tmp_path, splits=("test",), eval_extras=True)
    np.testing.assert_array_equal(sc.split("test").masks.numpy() > 0.5, b.hits["test"])
    sc = load_idr(tmp_path, splits=("train",), masks_as_alpha=True)
    sp = sc.split("train")
    assert sc.background == "alpha" and sp.alpha is not None
    assert float(sp.images[~b.hits["train"]].abs().max()) == 0.0  # composited on black


def test_split_json_and_errors(tmp_path):
    make_idr(tmp_path, n=4, masks=False, image_dir="images")
    (tmp_path / "split.json").write_text(json.dumps({"train": [0, 1], "test": [3]}))
    sc = load_idr(tmp_path, splits=("train", "test"))
    assert sc.split("test").names == ["003"]
    with pytest.raises(DataError, match="no mask"):
        load_idr(tmp_path, masks_as_alpha=True)
    (tmp_path / "images" / "004.png").write_bytes((tmp_path / "images" / "000.png").read_bytes())
    with pytest.raises(DataError, match="world_mat_4"):
        load_idr(tmp_path)


def test_outputs_in_world_frame(tmp_path):
    make_idr(tmp_path, n=3)
    sc = load_idr(tmp_path)
    # the sphere's centre maps back to the world-frame centre through the normalisation
    np.testing.assert_allclose(sc.norm.to_input(sc.norm.to_unit(SPHERE_C)), SPHERE_C)
    assert np.linalg.norm(sc.norm.to_unit(SPHERE_C)) < 1


def test_shape_and_reconstruct_accept_the_region_of_interest(tmp_path):
    """The keys the loaders' error messages suggest (bbox=, center=, radius=) are stage-1
    settings, and ``reconstruct`` takes them bare."""
    from voxnero.commands.reconstruct import split_overrides
    from voxnero.commands.shape import _load
    from voxnero.config import resolve
    from voxnero.shape.config import ShapeConfig

    make_idr(tmp_path, n=3)
    cfg = resolve(ShapeConfig, "shape", "tiny", ["radius=2.5", "center=[0.1, 0.2, 0.3]"])
    sc = _load(str(tmp_path), False, cfg)
    np.testing.assert_allclose(sc.norm.center, [0.1, 0.2, 0.3])
    assert sc.norm.scale == pytest.approx(2.5)
    cfg = resolve(ShapeConfig, "shape", "tiny", ["bbox=[-1, -1, -1, 1, 1, 3]"])
    np.testing.assert_allclose(_load(str(tmp_path), False, cfg).norm.center, [0, 0, 1])
    shape, material = split_overrides(["bbox=[0,0,0,1,1,1]", "material.iters=3"])
    assert shape == ["shape.bbox=[0,0,0,1,1,1]"] and material == ["material.iters=3"]


def test_info_shows_the_format(tmp_path, capsys):
    from voxnero.cli import main

    make_idr(tmp_path, n=9)
    assert main(["info", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "format      idr" in out and "split       test: 2 views" in out
    assert "scale_mat" in out
