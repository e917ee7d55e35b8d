"""Manifest forms (folder, YAML, CSV), their errors, and the cheap scene probe."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from voxnero.batch.manifest import SceneEntry, probe_scene, read_manifest
from voxnero.errors import ConfigError, DataError


def _fake_scene(root: Path, frames=True) -> Path:
    root.mkdir(parents=True)
    (root / "transforms_train.json").write_text(json.dumps({"frames": []} if frames else [1]))
    return root


def test_folder_of_scenes_sorted_hidden_skipped(tmp_path):
    for n in ["b", "a", ".cache"]:
        (tmp_path / n).mkdir()
    (tmp_path / "notes.txt").write_text("x")
    got = read_manifest(tmp_path)
    assert [e.name for e in got] == ["a", "b"]
    assert got[0].path == (tmp_path / "a").resolve() and got[0].overrides == []


def test_folder_that_is_a_scene_is_a_batch_of_one(tmp_path):
    s = _fake_scene(tmp_path / "one")
    assert read_manifest(s) == [SceneEntry("one", s.resolve(), [])]


def test_empty_folder_and_missing_path(tmp_path):
    with pytest.raises(DataError, match="no scene folders"):
        read_manifest(tmp_path)
    with pytest.raises(DataError, match="no such manifest"):
        read_manifest(tmp_path / "nope.yaml")
    (tmp_path / "list.txt").write_text("a\n")
    with pytest.raises(DataError, match="unknown manifest type"):
        read_manifest(tmp_path / "list.txt")


def test_yaml_relative_paths_names_and_overrides(tmp_path):
    m = tmp_path / "sub" / "m.yaml"
    m.parent.mkdir()
    m.write_text("scenes:\n"
                 "  - ../data/x\n"
                 "  - {path: /abs/y, name: why, overrides: [shape.iters=5, 'material.iters=7']}\n"
                 "  - {path: /abs/z, overrides: {shape.grid.res: [16, 32], eval.voxel: 0.02}}\n")
    got = read_manifest(m)
    assert [e.name for e in got] == ["x", "why", "z"]
    assert got[0].path == (tmp_path / "data" / "x").resolve()
    assert got[1].path == Path("/abs/y") and got[1].overrides == ["shape.iters=5",
                                                                  "material.iters=7"]
    assert got[2].overrides == ["shape.grid.res=[16, 32]", "eval.voxel=0.02"]


def test_yaml_plain_list_and_duplicate_names(tmp_path):
    m = tmp_path / "m.yml"
    m.write_text("- a/scene\n- b/scene\n- c/scene\n")
    assert [e.name for e in read_manifest(m)] == ["scene", "scene-2", "scene-3"]


@pytest.mark.parametrize("text, match", [
    ("", "lists no scenes"),
    ("scenes: []\n", "lists no scenes"),
    ("other: 1\n", "only 'scenes:'"),
    ("- {name: x}\n", "mapping with 'path'"),
    ("- {path: x, iters: 3}\n", "unknown key"),
    ("- {path: x, overrides: [iters]}\n", "not of the form key=value"),
    ("- [unclosed\n", "invalid YAML"),
])
def test_yaml_errors_name_the_problem(tmp_path, text, match):
    m = tmp_path / "m.yaml"
    m.write_text(text)
    with pytest.raises((ConfigError, DataError), match=match) as ei:
        read_manifest(m)
    assert str(m) in str(ei.value)


def test_csv_with_comments_and_overrides(tmp_path):
    m = tmp_path / "m.csv"
    m.write_text("# scenes of the night run\npath,name,overrides\n"
                 "s1,,\n/abs/s2,second,shape.iters=9 material.iters=3\n")
    got = read_manifest(m)
    assert [(e.name, e.path, e.overrides) for e in got] == [
        ("s1", (tmp_path / "s1").resolve(), []),
        ("second", Path("/abs/s2"), ["shape.iters=9", "material.iters=3"])]


def test_csv_without_path_column(tmp_path):
    m = tmp_path / "m.csv"
    m.write_text("scene,overrides\nx,\n")
    with pytest.raises(ConfigError, match="no 'path' column"):
        read_manifest(m)


def test_probe_scene(tmp_path):
    assert "not found" in probe_scene(tmp_path / "missing")
    (tmp_path / "file").write_text("x")
    assert "not a folder" in probe_scene(tmp_path / "file")
    (tmp_path / "empty").mkdir()
    assert "no known scene format" in probe_scene(tmp_path / "empty")
    assert probe_scene(_fake_scene(tmp_path / "ok")) is None
    assert "no 'frames' list" in probe_scene(_fake_scene(tmp_path / "noframes", frames=False))
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "transforms_train.json").write_text("{not json")
    msg = probe_scene(bad)
    assert "transforms_train.json" in msg and "unreadable pose file" in msg
