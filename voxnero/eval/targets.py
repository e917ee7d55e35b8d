"""What ``voxnero eval`` scores: the mesh of a run folder (or a mesh file) and the scene to score it
against (``--scene`` or the scene the run was trained on)."""

from __future__ import annotations

from pathlib import Path

from voxnero.config import read_meta


def is_stage2_run(target: str | Path) -> bool:
    """Whether ``target`` is a ``voxnero material`` output folder (model.glb + envmap.exr)."""
    p = Path(target)
    return p.is_dir() and (p / "model.glb").is_file() and (p / "envmap.exr").is_file()


def find_mesh(target: str | Path) -> Path:
    """The mesh to evaluate: ``target`` itself or ``target/mesh.ply``; for a stage-2 run, the
    stage-1 mesh it was fitted on (``_meta.mesh`` of its ``config.yaml``, same geometry as the
    exported model) or, when that file is gone, ``target/model.glb``."""
    from voxnero.errors import DataError

    p = Path(target)
    if p.is_dir():
        if (p / "mesh.ply").is_file():
            return p / "mesh.ply"
        if is_stage2_run(p):
            stage1 = read_meta(p).get("mesh")
            if stage1 and Path(stage1).is_file():
                return Path(stage1)
            return p / "model.glb"
        raise DataError("this folder holds no mesh.ply (nor model.glb + envmap.exr)", path=p,
                        fix="pass a finished run folder of 'voxnero shape' or 'voxnero "
                            "material', or a mesh file")
    if not p.exists():
        raise DataError("no such run folder or mesh file", path=p,
                        fix="pass a run folder holding mesh.ply or a .ply/.obj mesh")
    return p


def find_scene(target: str | Path, scene: str | None) -> Path:
    """``--scene`` if given, else ``_meta.scene`` of the run's ``config.yaml``."""
    from voxnero.errors import ConfigError

    if scene:
        return Path(scene)
    run = Path(target) if Path(target).is_dir() else Path(target).parent
    meta = read_meta(run)
    if meta.get("scene"):
        return Path(meta["scene"])
    raise ConfigError("no scene to evaluate against", fix="pass --scene SCENE_FOLDER (a scene with "
                      "test_mask/ and gt/test_depth/, e.g. a dev scene)")
