"""NeRO GlossySynthetic loader on a code-built scene: poses, depth, splits, hostile pickles."""

from __future__ import annotations

import json
import os
import pickle

import numpy as np
import pytest

from tests.fixtures.scenes import check_rays_hit_sphere, make_nero
from voxnero.cameras.rays import image_rays
from voxnero.data.nero import load_nero
from voxnero.errors import DataError


def test_rays_reproduce_rendered_sphere(tmp_path):
    b = make_nero(tmp_path)
    sc = load_nero(tmp_path)
    assert sc.format == "nero" and list(sc.splits) == ["train"]
    sp = sc.split("train")
    assert sp.n == 6 and sp.names == [str(k) for k in range(6)] and sp.depth is None
    check_rays_hit_sphere(sp, sc.norm, b.hits["train"], b.margins["train"])
    np.testing.assert_allclose(sp.cameras.K[0].numpy(), [[40, 0, 17.5], [0, 42, 15], [0, 0, 1]])


def test_depth_is_z_depth_in_unit_frame(tmp_path):
    b = make_nero(tmp_path)
    sc = load_nero(tmp_path, eval_extras=True)
    sp = sc.split("train")
    d = sp.depth.numpy()
    hit = b.hits["train"]
    assert (d[~hit] == 0).all() and (d[hit] > 0).all()
    # 16-bit quantisation of 15 units: half a level
    np.testing.assert_allclose(d[hit], b.depth["train"][hit] / sc.norm.scale,
                               atol=0.5 * 15 / 65535 / sc.norm.scale + 1e-6)
    # back-projected points lie on the unit-frame sphere (z-depth along the camera's +z)
    from tests.fixtures.scenes import SPHERE_C, SPHERE_R

    o, dirs = image_rays(sp.cameras, 0)
    cos = (dirs * sp.cameras.forward[0]).sum(-1)
    pts = (o + (sp.depth[0] / cos)[..., None] * dirs).numpy()[hit[0]]
    r = np.linalg.norm(pts - sc.norm.to_unit(SPHERE_C), axis=-1)
    np.testing.assert_allclose(r, SPHERE_R / sc.norm.scale, atol=1e-3)


def test_split_list(tmp_path):
    b = make_nero(tmp_path, split={"train": [0, 1, 2, 4], "test": [3, 5]})
    sc = load_nero(tmp_path, splits=("train", "test"))
    assert sc.split("test").names == ["3", "5"]
    check_rays_hit_sphere(sc.split("test"), sc.norm, b.hits["test"], b.margins["test"])
    # the normalisation uses all views, whatever the split
    assert sc.norm.to_dict() == load_nero(tmp_path, splits=("test",)).norm.to_dict()


def test_test_split_without_list_is_an_error(tmp_path):
    make_nero(tmp_path, n=2, with_depth=False)
    with pytest.raises(DataError, match="no split list") as e:
        load_nero(tmp_path, splits=("test",))
    assert "split.json" in str(e.value)


class _Evil:
    def __reduce__(self):
        return (os.system, ("echo pwned",))


def test_hostile_pickle_is_refused(tmp_path):
    make_nero(tmp_path, n=2, with_depth=False)
    with open(tmp_path / "1-camera.pkl", "wb") as f:
        pickle.dump([_Evil(), np.eye(3)], f)
    with pytest.raises(DataError, match="refusing to load") as e:
        load_nero(tmp_path)
    assert "1-camera.pkl" in str(e.value)


@pytest.mark.parametrize("pose,msg", [
    (np.eye(3), "pose is shape"),
    (np.full((3, 4), np.nan), "non-finite"),
])
def test_bad_pose(tmp_path, pose, msg):
    make_nero(tmp_path, n=2, with_depth=False)
    with open(tmp_path / "0-camera.pkl", "wb") as f:
        pickle.dump([pose, np.eye(3) * 40], f)
    with pytest.raises(DataError, match=msg) as e:
        load_nero(tmp_path)
    assert "0-camera.pkl" in str(e.value)


def test_split_json_with_unknown_view(tmp_path):
    make_nero(tmp_path, n=2, with_depth=False)
    (tmp_path / "split.json").write_text(json.dumps({"train": [0, 7]}))
    with pytest.raises(DataError, match=r"without a camera file: \['7'\]"):
        load_nero(tmp_path)
