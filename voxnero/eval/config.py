"""``EvalConfig``: the ``eval:`` section of a preset (``voxnero eval ... key=value``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Literal

from voxnero.config import Range, at_least
from voxnero.errors import ConfigError


@dataclass
class EvalConfig:
    """Settings of ``voxnero eval``. Defaults are the project's protocol; change them only to
    explore, and say so next to any number you report."""

    RANGES: ClassVar[dict[str, Range]] = {
        "voxel": Range(0.0, 1e6), "views": at_least(0), "images": at_least(0, 10000),
        "material_views": at_least(1, also=(-1,)), "material_spp": at_least(0, 4096),
        "material_subpixels": at_least(1, 1024), "cull_dilate": at_least(0, 64),
        "cull_edge_px": Range(0.0, 1e6),
        "material_passes": at_least(2, 64), "material_noise_share": Range(0.0, 1.0)}
    """Allowed values (:func:`voxnero.config.check_numbers`), checked before ``validate``."""

    split: str = "test"
    """Split of the scene holding the ground truth (masks, depth, normals)."""
    voxel: float = 0.01
    """Chamfer downsampling voxel, in the scene's input-frame units."""
    pred_pixels: Literal["unambiguous", "mask", "all"] = "unambiguous"
    """Pixels giving predicted Chamfer points (see :mod:`voxnero.eval.chamfer`)."""
    normal_source: Literal["vertex", "face"] = "vertex"
    """Predicted normals: interpolated vertex normals or face normals at the ray hit."""
    views: list[int] | None = None
    """Subset of view indices to evaluate (None: all views of the split)."""
    images: int = 2
    """Number of views written as comparison PNGs, normal maps and, for a stage-2 run, renders
    (0: none)."""
    material_views: int = 4
    """Stage-2 runs: test views rendered for the image / material metrics, evenly spread
    (-1: all; ``voxnero material`` itself uses all)."""
    material_spp: list[int] = field(default_factory=lambda: [64, 64, 64])
    """Stage-2 runs: samples per pixel of one render pass (cosine, GGX, env-map strategies).
    A view is the mean of 2 to ``material_passes`` passes (see there): 128 per strategy at
    least, 4x what ``voxnero material``'s own quick evaluation uses. The score is the model's,
    not the estimator's noise: on the corpus's true meshes, object PSNR rises by 1.7-6.9 dB
    from 8 samples on 4 subpixels to 128 on 16 (docs/BENCHMARKS.md, session 11)."""
    material_passes: int = 4
    """Stage-2 runs: at most this many passes per view; passes stop once the Monte Carlo noise
    of their mean, estimated from their spread, is ``material_noise_share`` of the error against
    the photo in the scored pixels (``voxnero.material.evaluate.render_converged``). A
    concave glossy object (the corpus's mug) needs more than 128 samples: its object PSNR at
    64 / 256 samples on the TRUE material is 24.2 / 28.2 dB (docs/BENCHMARKS.md, session 12).
    Relit renders of a view use the passes of its novel view. 4 bounds the cost at twice the
    session-11 evaluation (the knot: 3 passes, 363 s at load 5); 8 passes of the mug did not
    finish in 40 minutes on a loaded machine."""
    material_noise_share: float = 0.1
    """Stage-2 runs: the noise share of the error at which passes stop (noise then costs at
    most 0.46 dB of PSNR)."""
    material_relight: bool = True
    """Stage-2 runs: also render the views under the scene's relight maps
    (``test_relight_<env>``). They cost two thirds or more of a stage-2 evaluation; false
    scores the novel views and material maps alone (the same numbers as with them)."""
    material_subpixels: int = 16
    """Stage-2 runs: stratified points per pixel averaged in linear radiance, the box filter the
    photos were made with (the samples above are split among them; 1 = pixel centres)."""

    cull_dilate: int = 2
    """Captures without a GT mesh: dilation (pixels) of the training masks that cull the mesh
    before its silhouettes are scored (:mod:`voxnero.eval.silhouette`)."""

    cull_edge_px: float = 1.0
    """Captures without a GT mesh: triangles that straddle a mask boundary are split at their
    midpoints (same surface) until their edges are at most this many pixels long, so a vertex
    off the masks takes about a pixel of surface with it, not a whole coarse triangle; 0 = cull
    per vertex as extracted (:func:`voxnero.eval.silhouette.cull_refined`)."""

    def validate(self) -> None:
        """Check what ``RANGES`` cannot (single values are checked before)."""
        sp = list(self.material_spp)
        if len(sp) != 3 or sum(sp) < 1:
            raise ConfigError(f"eval.material_spp={self.material_spp} must be three counts "
                              "(cosine, GGX, env) >= 0 with at least one sample",
                              fix="e.g. eval.material_spp=[8,8,8]")
