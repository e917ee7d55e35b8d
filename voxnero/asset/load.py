"""Find and load the asset the user pointed at: a model file, a run folder or ground truth.

Sources (:func:`load_asset` picks by the path):

* ``model.glb`` (:mod:`voxnero.asset.gltf`), ``model.obj`` + ``.mtl`` (:mod:`voxnero.asset.obj`);
* a run folder: its ``model.glb`` (else ``model.obj``), plus the stage-1 ``mesh.ply`` when
  the run (or the stage-1 run its config names) has one, for the viewer;
* a ``voxnero reconstruct`` output folder: the asset of its ``material/`` run, with the stage-1
  mesh of its ``shape/`` run;
* ground truth: ``gt:SCENE`` or a scene folder holding ``gt/mesh.ply`` + ``gt/material.json``
  (:mod:`voxnero.asset.gt`).

A new format: its reader in ``voxnero/asset/<format>.py`` and one branch here.
"""

from __future__ import annotations

from pathlib import Path

from voxnero.asset.gltf import load_glb
from voxnero.asset.gt import load_gt
from voxnero.asset.model import Asset
from voxnero.asset.obj import load_obj
from voxnero.config import read_meta
from voxnero.errors import DataError


def _stage1_of(run: Path) -> Path | None:
    """The stage-1 mesh of a run folder: its own mesh.ply or the one its config.yaml names."""
    if (run / "mesh.ply").is_file():
        return run / "mesh.ply"
    mesh = read_meta(run).get("mesh")
    if mesh and Path(mesh).is_file():
        return Path(mesh)
    return None


def _load_run(run: Path) -> Asset | None:
    """The asset of a ``voxnero material`` run folder (model.glb, else model.obj), with its
    stage-1 mesh; None when the folder holds neither model."""
    for name, fn in (("model.glb", load_glb), ("model.obj", load_obj)):
        if (run / name).is_file():
            a = fn(run / name)
            a.stage1_mesh = _stage1_of(run)
            return a
    return None


def load_asset(target: str | Path) -> Asset:
    """Load what the user pointed at (see the module docstring for the accepted forms).

    Args:
        target: ``model.glb``, ``model.obj``, a ``material`` or ``reconstruct`` run folder,
            ``gt:SCENE`` or a scene folder with ``gt/``.

    Returns:
        The :class:`Asset` in the scene's input frame.

    Raises:
        DataError: nothing loadable there (the message lists what was looked for).
    """
    s = str(target)
    if s.startswith("gt:"):
        return load_gt(s[3:])
    p = Path(s)
    if p.is_file():
        suf = p.suffix.lower()
        if suf == ".glb":
            return load_glb(p)
        if suf == ".obj":
            return load_obj(p)
        raise DataError(f"unsupported asset file type {suf!r}", path=p,
                        fix="pass model.glb / model.obj, a run folder or gt:SCENE")
    if p.is_dir():
        a = _load_run(p)
        if a is None and (p / "material").is_dir():  # a 'voxnero reconstruct' folder
            a = _load_run(p / "material")
            if a is not None and (p / "shape" / "mesh.ply").is_file():
                a.stage1_mesh = p / "shape" / "mesh.ply"
        if a is not None:
            return a
        if (p / "gt" / "mesh.ply").is_file():
            return load_gt(p)
        raise DataError("no asset here: looked for model.glb, model.obj, material/model.glb, "
                        "material/model.obj, gt/mesh.ply", path=p,
                        fix="pass a 'voxnero material' or 'voxnero reconstruct' output folder "
                            "(after its stage 2), a model file or gt:SCENE")
    raise DataError("no such file or folder", path=p,
                    fix="pass model.glb / model.obj, a run folder or gt:SCENE")
