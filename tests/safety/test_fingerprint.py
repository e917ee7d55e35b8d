"""voxnero/safety/fingerprint.py: a checkpoint resumes only with its scene and the settings that
shaped it; ``--fresh`` starts over."""

from __future__ import annotations

import shutil

import pytest

from tests.safety.safety_helpers import blender_scene, run_cli, shape_argv, snapshot
from voxnero.config import from_dict, to_dict
from voxnero.errors import RunFolderError
from voxnero.safety import fingerprint
from voxnero.shape.config import ShapeConfig


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    root = tmp_path_factory.mktemp("fp")
    return blender_scene(root / "a"), blender_scene(root / "b", n_train=4, seed=1)


def test_another_scene_or_other_settings_are_refused_and_fresh_starts_over(tmp_path, capsys,
                                                                            scenes):
    """``voxnero shape OTHER_SCENE --out FINISHED_RUN`` said "resumed ... at step 6", exit 0,
    and kept the old scene's mesh."""
    a, b = scenes
    out = tmp_path / "run"
    rc, _, err = run_cli(shape_argv(a, out), capsys)
    assert rc == 0, err
    good = snapshot(out)
    rc, _, err = run_cli(shape_argv(b, out), capsys)
    assert rc == 2 and "made from another scene" in err and "--fresh" in err, err
    assert str(out / "checkpoint.pt") in err
    assert snapshot(out) == good
    rc, _, err = run_cli(shape_argv(a, out, "loss.eikonal=0.2"), capsys)
    assert rc == 2 and "shape.loss.eikonal: 0.1 -> 0.2" in err, err
    assert snapshot(out) == good
    # the same scene elsewhere (copied) and a setting that does not shape the model resume
    moved = tmp_path / "moved"
    shutil.copytree(a, moved)
    rc, stdout, err = run_cli(shape_argv(moved, out, "mesh_res=12"), capsys)
    assert rc == 0 and "resumed from" in stdout, err
    # --fresh: the other scene from scratch
    rc, stdout, err = run_cli(shape_argv(b, out, "--fresh"), capsys)
    assert rc == 0, err
    assert "resumed" not in stdout and "--fresh: removed checkpoint.pt" in stdout
    assert str(b) in (out / "config.yaml").read_text()


def test_free_keys_are_config_keys():
    """Every FREE_ON_RESUME key names a setting (a typo would silently shape nothing)."""
    from voxnero.material.config import MaterialConfig

    for cls in (ShapeConfig, MaterialConfig):
        keys = set(fingerprint._flatten(to_dict(cls())))
        assert set(cls.FREE_ON_RESUME) <= keys
        assert not set(cls.FREE_ON_RESUME) & set(fingerprint.model_settings(cls()))


def test_check_resume_names_sources_and_keys(tmp_path):
    cfg = from_dict(ShapeConfig, {"iters": 10})
    now = fingerprint.make(cfg, scene="aaaa")
    assert fingerprint.check_resume(now, now, tmp_path / "c.pt")
    assert not fingerprint.check_resume(None, now, tmp_path / "c.pt")  # before fingerprints
    with pytest.raises(RunFolderError, match="another scene"):
        fingerprint.check_resume(fingerprint.make(cfg, scene="bbbb"), now, tmp_path / "c.pt")
    other = fingerprint.make(from_dict(ShapeConfig, {"iters": 20}), scene="aaaa")
    with pytest.raises(RunFolderError, match=r"shape\.iters: 20 -> 10"):
        fingerprint.check_resume(other, now, tmp_path / "c.pt", "shape")
