"""Fixtures of the batch tests: one tiny analytic scene and stage sizes that take seconds.

Test modules get them as fixtures (not ``from conftest import``: several test folders have a
conftest.py, so the module name ``conftest`` is ambiguous).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

# The sphere start (shape.coarse.iters=0): on 6 views of 32 px the presets' coarse free-space
# stage carves a hull of 0.1 % of its voxels, and the 40 steps then leave no surface at all.
TINY_STAGES = [
    "shape.coarse.iters=0", "shape.iters=40", "shape.grid.res=[16]", "shape.grid.upsample_at=[]",
    "shape.grid.feat_res=8", "shape.sampling.rays=256", "shape.mesh_res=32",
    "shape.eval_every_s=0", "shape.preview_every=0",
    "material.iters=10", "material.batch=256", "material.bg_batch=1024",
    "material.texture_size=32", "material.eval_views=1", "material.light.env_height=[8]",
    "material.render.spp_cos=2", "material.render.spp_ggx=2", "material.render.spp_env=2",
    "material.render.eval_scale=1", "material.threads=1", "material.max_pixels=5000",
]
"""Overrides that make ``voxnero reconstruct`` on a 32² scene take seconds (quality: none)."""


@pytest.fixture(scope="session")
def tiny_stages() -> list[str]:
    """A copy of :data:`TINY_STAGES`."""
    return list(TINY_STAGES)


@pytest.fixture(scope="session")
def tiny_scene(tmp_path_factory) -> Path:
    """An analytic sphere scene (32², 6 train + 2 test views, ground truth in ``gt/``)."""
    from voxnero.config import resolve
    from voxnero.synth.config import SynthConfig
    from voxnero.synth.make import make_scene

    cfg = resolve(SynthConfig, "synth", "tiny", ["resolution=32", "n_train=6", "n_test=2",
                                                  "spp=1", "max_depth=1"])
    return make_scene("sphere", tmp_path_factory.mktemp("scene") / "sphere", cfg,
                      progress=False)


@pytest.fixture
def scene_copies(tiny_scene, tmp_path):
    """``make(names)`` copies the tiny scene to ``tmp_path/scenes/<name>`` for each name."""

    def make(names: list[str]) -> Path:
        root = tmp_path / "scenes"
        for n in names:
            shutil.copytree(tiny_scene, root / n)
        return root

    return make
