"""Analytic test scenes (sphere, torus, two spheres) rendered exactly, in the NeRF-synthetic format.

Python API: ``voxnero.synth.make_scene(shape, out_dir, cfg)`` with a
:class:`voxnero.synth.config.SynthConfig`; command line: ``voxnero synth SHAPE --preset tiny
--out DIR [key=value ...]``. Modules: ``shapes`` (intersection, normals, SDF, GT meshes),
``materials``, ``envmaps`` (procedural/constant/file HDR maps), ``camera_rig`` (dev-scene-like
Fibonacci cameras), ``pathtrace`` (Monte Carlo rendering), ``aov`` (coverage and GT maps),
``scenes`` (the named recipes), ``writer`` (files), ``make`` (orchestration).
"""

from __future__ import annotations

from typing import Any

__all__ = ["SHAPES", "SynthConfig", "make_scene"]


def __getattr__(name: str) -> Any:  # lazy: importing a submodule stays light
    if name == "make_scene":
        from voxnero.synth.make import make_scene

        return make_scene
    if name in ("SynthConfig", "SHAPES"):
        from voxnero.synth import config

        return getattr(config, name)
    raise AttributeError(f"module 'voxnero.synth' has no attribute {name!r}")
