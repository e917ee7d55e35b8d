"""Configuration of stage 1 (``voxnero shape``): one small dataclass per component.

Presets set these in the ``shape:`` section of ``voxnero/configs/<preset>.yaml``; every key
can be overridden on the command line (``grid.res=[48, 96]``, ``iters=3000``). Schedules are
given as fractions of ``iters`` so that a preset scales with its length.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar, Literal

from voxnero.config import (
    BIG_COUNT,
    FRACTION,
    LEARNING_RATE,
    SEED,
    THREADS,
    WEIGHT,
    Range,
    Switch,
    at_least,
    positive,
)
from voxnero.errors import ConfigError


@dataclass
class GridConfig:
    """SDF and feature grids (unit frame, cube ``[-bound, bound]³``)."""

    RANGES: ClassVar[dict[str, Range]] = {
        "res": at_least(4, 1024), "upsample_at": Range(0.0, 1.0, lo_open=True, hi_open=True),
        "bound": positive(10.0), "init_radius": positive(1.5), "init_candidates": positive(1.5),
        "init_margin": Range(-100.0, 100.0),
        "fd_step": positive(16.0), "grad_smooth": Range(0.0, 16.0),
        "update_smooth": Range(0.0, 16.0), "coarse_step": at_least(0, 64),
        "feat_res": at_least(1, 512),
        "feat_dim": at_least(1, 256)}
    """Allowed values (:func:`voxnero.config.check_numbers`); the units are voxels, the unit
    frame (``bound``, radii: the object lies in the unit sphere) and dB."""

    res: list[int] = field(default_factory=lambda: [48, 96])
    """SDF grid resolutions, coarse to fine; the grid is trilinearly upsampled between them."""
    upsample_at: list[float] = field(default_factory=lambda: [0.5])
    """Fractions of ``iters`` at which to move to the next resolution (len(res) − 1 values)."""
    bound: float = 1.05
    init_radius: float = 0.7
    """Radius of the initial SDF sphere: start around the object and carve inward, but leave
    background visible in every view (the unit sphere is the largest one every view sees whole):
    from 0.95 nothing was carved in 90 s on sphere_gold, the env map had no background to learn."""
    init_candidates: list[float] = field(default_factory=lambda: [0.5])
    """Other initial radii tried against ``init_radius``; [] = ``init_radius`` only.
    A mirror barely moves from where it starts: it can reflect the environment so that a shell of
    the initial sphere looks like background (a mirror sphere of radius 0.45 off the centre kept
    one from 0.7: Chamfer 0.25; from 0.5: 0.006), and it barely grows because its rim reflects
    what lies behind it (sphere_gold, radius 0.8, from 0.5: 0.070; from 0.7: 0.011). So the
    program tries both: a race of complete runs in ``starts/r<radius>/``, each with its own
    checkpoints, judged on the final model's PSNR over ``fit_rays`` fixed training pixels
    (:func:`voxnero.shape.starts.race`); it costs one extra run per candidate. (A shorter first
    look on early training PSNR was removed: early PSNR favours a start inside a mirror that
    later loses, docs/STAGE1.md, finding 13.)"""
    init_margin: float = 0.0
    """dB by which another start's fit must beat the first start's (the coarse stage's start
    when ``coarse.iters`` > 0, else ``init_radius``'s) to replace it. 0: the final fits the race
    compares are deterministic and starts that end alike fit alike. Every preset takes the
    better fit. Until session 38 they asked 0.5 dB of a sphere against the carved start, set for
    dtu_scan97 (the sphere won by 0.4 dB with a rounder surface, docs/STAGE1.md finding 20),
    which no longer races (a near background, finding 21); with the grown hull that margin
    kept sphere_gold's carved start, 0.31 dB worse, at 0.0058 against 0.0038 (finding 39)."""
    normals: Literal["analytic", "fd"] = "analytic"
    fd_step: float = 1.0
    """Central-difference half-step in voxels (normals: fd)."""
    grad_smooth: float = 1.0
    """Gaussian blur (sigma, in voxels of the current grid) of the SDF grid's gradient before
    each optimiser step (0 = off): spreads each ray's update over neighbours. A sigma fixed in
    space (2 voxels at 96³) made both preview runs diverge after the upsampling: Adam scales
    the blurred tails of tiny gradients up to full lr-sized steps, the grid filled with noise
    (mean squared Laplacian 1.6e3 voxel units, Chamfer 1.1)."""
    update_smooth: float = 0.0
    """Gaussian blur (sigma, in voxels of the current grid) of each Adam *update* of the SDF
    grid (0 = off): the grid moves by ``blur(new - old)``. Unlike ``grad_smooth``, whose blurred
    gradient Adam divides back into per-voxel steps of about lr, the change of the surface is
    smooth at the scale sigma whatever the optimiser does, so no voxel-scale bumps can grow; a
    part thicker than a few voxels (a chair leg) is not penalised, only its updates are."""
    coarse_step: int = 0
    """Block side k (voxels) of a second SDF step in the finishing phase (from
    ``neus.final_at``; 0 = off, :mod:`voxnero.shape.coarse_step`): the SDF gradient averaged
    over k³ blocks gets its own Adam step, scaled by its reliability m²/v and upsampled onto the
    grid, so a face follows the outline that pulls its edges. k = 8 in the preview, standard and
    quality presets (docs/STAGE1.md finding 32), carved start, medians of the ten corpus scenes:
    `preview` 0.81 -> 0.72 px (table 0.79 -> 0.63), `standard` 0.80 -> 0.75 px (table 0.86 ->
    0.77, gear 0.96 -> 0.88), the worst (the bowl) unchanged; the duck and the bunny lose 0.04 px
    at `preview`. Off here so that the tiny test preset and bare configs keep their behaviour.
    Its moments are not checkpointed: a resumed run restarts them."""
    feat_res: int = 8
    feat_dim: int = 8
    res_auto: bool = True
    """Cap ``res`` (and scale the sample counts) so that a voxel is not finer than one pixel's
    footprint at the object's distance (:mod:`voxnero.shape.adaptive`); the preset's values are
    upper bounds. Decision and evidence in ``RUN/decisions.json``."""


@dataclass
class CoarseConfig:
    """The coarse free-space stage that gives the SDF its start (:mod:`voxnero.shape.coarse`,
    :func:`voxnero.shape.starts.coarse_start`): a density grid carves the space the photos see
    through, and the filled occupancy becomes the SDF's first surface instead of a sphere."""

    RANGES: ClassVar[dict[str, Range]] = {
        "iters": at_least(0, BIG_COUNT), "near_iters": at_least(0, BIG_COUNT),
        "res": at_least(8, 1024), "samples": at_least(2, 4096),
        "rays": at_least(1, BIG_COUNT), "feat_dim": at_least(1, 256), "hidden": at_least(1, 1024),
        "alpha_init": Range(0.0, 1.0, lo_open=True, hi_open=True), "lr_grid": LEARNING_RATE,
        "lr_head": LEARNING_RATE, "tv": WEIGHT, "margin": Range(0.0, 64.0),
        "env_height": at_least(0, 4096),
        "s_start": positive(1e9), "normal_smooth": WEIGHT, "sdf_res": at_least(4, 1024),
        "sdf_first": Range(0.0, 1.0, lo_open=True),
        "sdf_upsample_at": Range(0.0, 1.0, lo_open=True, hi_open=True),
        "smooth": Range(0.0, 16.0), "close": at_least(0, 16),
        "update_smooth": Range(0.0, 16.0), "lr_sdf_factor": positive(1e3),
        "threshold": Range(0.0, 1.0, lo_open=True, hi_open=True),
        "bg_grow": at_least(0, 64), "bg_quantile": Range(0.0, 1.0),
        "open_k": Range(1.0, 100.0), "open_shell": positive(64.0), "open_hold": Range(0.0, 1.0),
        "open_margin": Range(0.0, 10.0), "open_tie": Range(0.0, 10.0),
        "open_contrast": Range(0.0, 1.0), "open_gate": Range(0.0, 1.0)}

    iters: int = 0
    """Steps of the coarse stage; 0 = off (the SDF starts from the sphere ``grid.init_radius``
    and the race of ``grid.init_candidates``)."""
    res: int = 96
    """Samples per axis of the density grid (capped by the pixel footprint like the SDF grid)."""
    samples: int = 128
    """Stratified samples per ray inside the bounding sphere."""
    rays: int = 4096
    feat_dim: int = 8
    hidden: int = 32
    alpha_init: float = 1e-3
    """Opacity per voxel length of the initial uniform density."""
    lr_grid: float = 0.1
    lr_head: float = 1e-3
    tv: float = 0.0
    """Weight of the total variation of the raw density."""
    env_height: int = 256
    """Most rows of the env map the coarse stage fits (0: the main stage's map); the rows are
    those whose texel spans 4 pixels of the photos (:func:`voxnero.shape.adaptive.env_rows`),
    at least ``light.env_height``, at most this. The SDF stage then goes on with the map
    area-averaged to ``light.env_height``. The photos show
    the background at 0.16° per pixel (256², 40°); what the map cannot draw, the density draws
    with floaters, among which thin parts are lost. Corpus `preview`, coarse start alone, rows
    64 / 128 / 256: table_oak 16.8 / 4.3 / 0.86 px, gear 2.07 / 1.87 / 1.80, bunny 1.35 / 1.26 /
    1.63, median 1.25 / 1.20 / 1.09 px (docs/STAGE1.md finding 19)."""
    near_iters: int = 0
    """Steps of stage 1 (instead of ``iters``) when the background is near; such a scene never
    races sphere starts (:func:`voxnero.shape.starts.near_start`). 0 = ``iters``."""
    bg_grow: int = 0
    """Voxels of the density grid by which the hull may grow into corners the photos show as
    object: seen against a background pixel in fewer of their views than the hull's own core
    (:func:`voxnero.shape.hull.grow_seen_as_object`, :mod:`voxnero.shape.bg_votes`). A
    mirror's density can sit below its shiny face, and its hull then lacks that face (the
    gear's tooth tops, docs/STAGE1.md finding 38). Not with a near background (a capture's
    table: the coarse stage's map does not draw it). 0 = off. `standard` and `quality` 4:
    corpus median 0.595 -> 0.584 px, worst 2.61 -> 2.35, the gear's genus right at three seeds,
    the pretzel's pits gone (with ``grid.init_margin`` 0, so that sphere_gold's race keeps its
    better sphere start, finding 39). `preview` 4 since session 50: its 300-step hull of a
    smooth metal lacked whole faces (held-out vase 3.37 -> 1.42 px, teapot 2.33 -> 1.73; corpus
    median 0.66 -> 0.63, worst 2.93 -> 2.64; the gear 0.79 -> 0.97, with ``bg_quantile`` 0.9,
    finding 55)."""
    bg_quantile: float = 0.95
    """Quantile of the hull core's background ratio that a grown corner must stay below.
    `preview` 0.9: its 300-step core is fatter and holds corners seen against the background
    (the gear 1.14 -> 0.97 px, the bowl 2.59 -> 2.64; docs/STAGE1.md finding 55)."""
    open_worst: bool = False
    """Propose one more start to the race (:func:`voxnero.shape.starts.race`,
    :mod:`voxnero.shape.proposals`): after the carved start's complete run, the surface patch
    whose photos it explains worst (error above ``open_k`` times the surface's median) may be
    the lid the hull puts over a cavity (a mug's, a bowl's, a ladle's: the photos see into it
    but never through it, so the density fills it); the carved start is made a shell
    2·``open_shell`` coarse voxels thick, opened under that patch, and runs complete too. The
    race keeps it if it fits ``open_margin`` dB better and its mesh has the carved run's genus
    (an opened lid adds no tunnel), or if it ties (``open_tie``, ``open_contrast``). Off here
    (`preview`'s fits do not tell an open cavity from the lid, finding 28, and its 4 minutes
    hold no third run); on in `standard` and `quality`, for every carved run (``open_gate``
    0): on the corpus it opens the mug (1.96 -> 0.82 px, normal error 12.2 -> 4.5 deg) and,
    by ``open_tie``, the bowl (2.34 -> 1.22 px), and the held-out ladle (2.09 -> 1.17 px),
    whose lid the material gate of sessions 44-50 let through (docs/STAGE1.md findings 44-48,
    57)."""
    open_k: float = 1.5
    """Error above this many times the surface's median marks the worst patch."""
    open_shell: float = 1.5
    """Half the wall thickness of the opened start, in coarse voxels (the hollow start of
    finding 42). 1.5: the bowl 1.81 px at 2 (genus 7), 1.24 at 1.5 (genus 0), 1.04 at 1
    (genus 1) (docs/STAGE1.md findings 47-48)."""
    open_hold: float = 0.2
    """Fraction of ``iters`` during which the opened start's SDF is held still (learning rate
    0) while its colour features, material and light form around the open shape: moved from
    the first step, the bowl's rim grows a membrane by step 300 and the lid is back
    (docs/STAGE1.md findings 47-48). 0 = none."""
    open_margin: float = 0.1
    """dB by which the opened start must fit better than the carved one to be kept: a
    solid object's opened start can tie (table_oak +0.008 dB, 0.63 -> 0.95 px) where an open
    cavity wins clearly (mug_glaze +0.28 dB, 1.92 -> 1.08 px; docs/STAGE1.md finding 44)."""
    open_tie: float = 0.25
    """dB within which an opened start that fits worse than the carved one still ties with
    it, and is kept if its own worst-fitted patch is painted like the surface around it (one
    material where the carved run needed a painted lid:
    :func:`voxnero.shape.starts.tied_with_one_material`). 0 = off."""
    open_contrast: float = 0.3
    """A lid is painted with another material than the walls it joins, to explain the cavity
    it hides; a solid object's worst patch (edges, its hardest material) has its
    surroundings' (docs/STAGE1.md finding 46). An opened start that ties (``open_tie``) is kept
    only if the carved run's worst patch differs from the ring of surface around it by at
    least this much (largest absolute difference of the mean metallic, roughness and linear
    albedo channels, :func:`voxnero.shape.proposals.material_contrast`) and its own by less."""
    open_gate: float = 0.0
    """Run the opened start only if the carved run's worst patch's material contrast is at
    least this (saves its complete run on objects whose worst patch is painted like its
    surroundings). 0 = for every carved run, the photos and the genus judge: at 0.3 (sessions
    44-50) the held-out ladle's lid (contrast 0.20) was never opened (docs/STAGE1.md finding
    57)."""
    race: bool = True
    """Race the coarse start against the sphere of ``grid.init_radius`` (complete runs, the
    better final fit kept, :func:`voxnero.shape.starts.race`): a mirror's density can be a
    bumpy or hollow hull where the sphere start carves a smooth surface."""
    s_start: float = 150.0
    """NeuS sharpness at the first SDF step after a coarse start (``neus.s_start`` is the
    sphere start's): the hull is within a few pixels, a blurry start erodes thin parts."""
    normal_smooth: float = 0.0
    """``loss.normal_smooth`` after a coarse start."""
    update_smooth: float = 1.0
    """``grid.update_smooth`` after a coarse start (replacing ``grid.grad_smooth``): each step
    of the SDF is blurred by this sigma (voxels), so no voxel-scale bumps grow while rods keep
    their width (docs/STAGE1.md, finding 18)."""
    lr_sdf_factor: float = 4.0
    """Factor on ``optim.lr_sdf`` after a coarse start: the update blur spreads a step over
    the neighbours, so a sheet moves about half as far per step at sigma 1 (corpus `preview`,
    coarse start only, factors 1 / 2 / 4 on five scenes: median Chamfer 1.85 / 1.53 / 1.12 px,
    docs/STAGE1.md finding 18)."""
    sdf_res: int = 96
    """SDF grid resolution after a coarse start (capped by the pixel footprint over the fitted
    box); ``grid.res`` is the sphere start's schedule."""
    sdf_first: float = 0.5
    """Resolution of the SDF stage's first grid after a coarse start, as a fraction of
    ``sdf_res``; below 1 that grid is upsampled to ``sdf_res`` at ``sdf_upsample_at`` of the
    steps, 1 = one grid throughout. Coarse to fine, as the sphere start's ``grid.res``: the
    bumps and tiny handles of a metal's hull (its density is noisy, finding 18) do not fit in
    the first grid, so its large shape settles before the fine grid adds detail (corpus
    ``preview``, carved start alone: median 1.06 -> 0.91 px, normal error 11.5 -> 9.3 deg, right
    genus 3 -> 5 of 6; the gear 2.00 -> 0.96, the bunny 1.38 -> 0.58, the pretzel 1.05 -> 0.33;
    docs/STAGE1.md finding 24)."""
    sdf_upsample_at: float = 0.5
    """Fraction of the steps at which the first grid (``sdf_first``) becomes ``sdf_res``."""
    fit_box: bool = True
    """Fit the SDF grid's cube to the object found (plus ``margin``): the preset's resolutions
    then resolve a small object as finely as a large one (capped by the pixel footprint)."""
    margin: float = 4.0
    """Margin of the fitted cube, in voxels of the coarse grid."""
    smooth: float = 0.0
    """Gaussian blur (sigma, coarse voxels) of the opacity before the threshold: removes the
    voxel-scale tunnels of a noisy density (hull genus 94 -> 1 on knot_chrome at sigma 1), but
    also thin parts whose opacity sits in one or two voxels (table_oak: 51 voxels left)."""
    close: int = 1
    """Iterations of a morphological closing (3×3×3 cube) of the occupied voxels before
    the fill: closes tunnels up to 2·close voxels wide and never removes an occupied
    voxel, so thin parts stay (the alternative to ``smooth``)."""
    threshold: float = 0.1
    """Opacity per voxel length above which a voxel is occupied (the shell that is filled).
    Low, so that the shell is closed: a hole in it lets the fill leak (hull Chamfer after 300
    steps at 0.05 / 0.1 / 0.3: knot_chrome 1.3 / 1.8 / 8.2 px, table_oak 2.0 / 1.7 / 15.8 px)."""


@dataclass
class SamplingConfig:
    """Ray batch and sample placement."""

    RANGES: ClassVar[dict[str, Range]] = {
        "rays": at_least(1, BIG_COUNT), "coarse": at_least(2, 4096), "fine": at_least(0, 4096),
        "coarse_keep": at_least(0, 4096), "radius": positive(10.0),
        "error_frac": FRACTION, "error_tile": at_least(1, 4096),
        "error_decay": Range(0.0, 1.0, lo_open=True), "coarse_final": at_least(0, 4096)}

    rays: int = 4096
    coarse: int = 32
    """Stratified samples per ray of the no-grad coarse pass (also kept for rendering)."""
    fine: int = 16
    """Importance samples per ray drawn from the coarse NeuS weights."""
    coarse_keep: int = 16
    """How many evenly spaced coarse samples join the fine ones in the rendered set."""
    coarse_final: int = 128
    """Coarse samples per ray from ``neus.final_at`` of the run on (0 = ``coarse`` throughout),
    so that the fine samples find a grazing ray's shallow crossing of an edge once the
    sharpness rises to ``neus.s_final`` (docs/STAGE1.md finding 30)."""
    radius: float = 1.0
    """Bounding sphere of the object in the unit frame."""
    error_frac: float = 0.5
    """Share of each training batch (coarse and SDF stage) drawn where the render and the
    photo disagree, in proportion to a running error per image tile
    (:class:`voxnero.cameras.error_pixels.ErrorGuidedPixels`); 0 = uniform pixels. The race's
    judge and the light switches always measure on uniform pixels. The pixels that place a
    thin part or a mirror's curvature are few (silhouettes in grazing views, reflections);
    uniform batches give them a small share. Corpus, `preview`, coarse start alone, 0 → 0.5:
    Chamfer median 1.08 → 1.06 px, normal error median 14.0° → 11.5° (knot 0.85 → 0.58 px,
    12.9° → 6.3°; bunny 2.11 → 1.38 px; worst changes gear 1.90 → 2.00 px, mug 15.1° →
    16.7°; docs/STAGE1.md finding 23)."""
    error_tile: int = 8
    """Tile side in pixels of the error map."""
    error_decay: float = 0.5
    """Weight of a new measurement in a tile's running error."""
    subpixel: bool = False
    """Training rays through a uniform point inside their pixel (the photos' box filter: a
    pixel is the mean over its area) instead of its centre."""


@dataclass
class NeusConfig:
    """Scheduled NeuS sharpness (1/length)."""

    RANGES: ClassVar[dict[str, Range]] = {
        "s_start": positive(1e9), "s_end": positive(1e9), "ramp": FRACTION,
        "s_final": positive(1e9), "final_at": FRACTION}

    alpha: Literal["sequence", "section"] = "sequence"
    """"sequence": opacity of the interval between consecutive samples from their SDF values
    (NeuS eq. 13 as such); "section": NeuS's per-sample sections with the SDF extrapolated by the
    directional derivative ∇f·d. On a grid the derivative path made the colour gradient *grow*
    a too-large sphere (the slope between neighbouring voxels dominates), so "section" did not
    carve at all (docs/STAGE1.md)."""
    s_start: float = 30.0
    s_end: float = 400.0
    ramp: float = 0.6
    """Fraction of ``iters`` over which s rises geometrically from s_start to s_end."""
    dip: bool = False
    """With ``alpha`` = "sequence": an interval whose SDF dips between its two samples (a ray
    grazing a thin rod or a rounded edge at the outline) gets the opacity of the approach to
    the dip, found from the samples' values and slopes (``shape.neus.alpha_from_sequence_min``,
    1.03x the render's time); without it such a ray renders too transparent, the outline of a
    thin part too thin, and the fit widens the part. On in the shipped presets; off here so
    that the unit tests' tiny runs keep the plain sequence opacity. Corpus (docs/STAGE1.md
    findings 35-37): `standard` Chamfer median 0.75 -> 0.60 px (chair 0.73 -> 0.56, frame
    0.92 -> 0.76, table 0.77 -> 0.63), `preview` 0.71 -> 0.65; stage 2 relights its
    `standard` meshes at a median of 26.17 dB (finding 37; the pretzel's pits cost it 2 dB).
    The gear's genus depends on the seed with or without it (its carved start loses the tops
    of the teeth)."""
    dip_detach: bool = False
    """With ``dip``: the slopes along the ray place and shape the dip but carry no gradient;
    only the two samples' SDF values do. The slopes are the grid's analytic gradient, so
    through them the dip's opacity pulls on the differences between neighbouring voxels
    (finding 36: on the gear 0.90 -> 0.83 / 0.85 px, normal error median 3.1 -> 2.8-2.9 deg)."""
    s_final: float = 1600.0
    """Sharpness at the end of the run: from ``final_at`` of ``iters`` on, s rises
    geometrically from its scheduled value to ``s_final`` (≤ ``s_end``: no rise).
    At s = 400 a grazing ray through the trilinear grid's rounded edge gets too little opacity
    (the outline of the true shape renders soft and notched), and the fit fattens the faces to
    make it up; carving needs the softer s, so the sharp one comes last. Corpus, `preview`:
    frame 1.05 → 0.97, table 1.04 → 0.91 px, no scene worse by more than 0.02 px (docs/STAGE1.md
    finding 30)."""
    final_at: float = 0.8
    """Fraction of ``iters`` where the finishing phase (``s_final``,
    ``sampling.coarse_final``) starts."""


@dataclass
class LightConfig:
    """Light and material model switches ("auto" is decided from the data by
    :mod:`voxnero.shape.adaptive` and recorded in ``RUN/decisions.json``; on/off always win)."""

    RANGES: ClassVar[dict[str, Range]] = {
        "env_height": at_least(4, 4096), "env_init": positive(1e6),
        "max_log_radiance": Range(-20.0, 80.0), "decide_at": FRACTION,
        "self_occlusion_min": FRACTION, "decide_until": FRACTION,
        "decide_rays": at_least(1, BIG_COUNT), "occlusion_offset": Range(0.0, 100.0),
        "occlusion_t_near": Range(0.0, 100.0), "occlusion_smooth": at_least(0, 1000),
        "hidden": at_least(1, 4096), "init_roughness": positive(1.0),
        "init_roughness_candidates": positive(1.0), "near_res": at_least(2, 512),
        "near_samples": at_least(1, 1024), "near_far_ratio": Range(1.0, 1e6, lo_open=True),
        "near_lr": LEARNING_RATE, "exposure_min_spread": Range(0.0, 10.0),
        "exposure_min_agreement": Range(-1.0, 1.0),
        "exposure_pixels": at_least(16, BIG_COUNT), "exposure_lr": LEARNING_RATE}
    """``max_log_radiance`` <= 80: exp(80) ~ 5.5e34 still fits a float32."""

    env_height: int = 64
    """Height of the learnable equirectangular env map (width = 2 × height)."""
    env_init: float = 0.5
    """Initial env radiance (linear)."""
    max_log_radiance: float = 4.0
    diffuse: Literal["principled", "weighted"] = "weighted"
    """The diffuse lobe the split-sum shading uses (``shape.shading.shade``): "weighted" =
    Lambert under the dielectric interface (``1 - E_d(n.v)``), dark at grazing views;
    "principled" = the Disney (Burley 2015) lobe with retro-reflection that rendered the photos
    and that stage 2 fits, by its closed-form directional albedo
    (``render.brdf.principled_diffuse_albedo``; at n.v = 0.1, 1.9x (r = 0.1) to 1.4x (r = 0.9)
    the weighted lobe's). Measured with ``irradiance`` = "exact" on the corpus at `standard`
    (docs/STAGE1.md finding 27): normal error median 6.66 -> 5.92 deg, Chamfer median 0.85
    unchanged, bunny 0.55 -> 0.43 px, but the metals' meshes relit worse (knot -1.8 dB,
    pretzel -3.0 dB at seed 0, -0.4 at seed 1; the relight median 26.28 -> 24.84 dB), so not
    the default."""
    irradiance: Literal["sh9", "exact"] = "sh9"
    """How the env map lights the diffuse lobe (``fields.lights.EnvLight``): its order-2 SH
    projection (4 ms a step with its gradient at 64 rows on one thread), which rings around a
    sun (a face at 90 degrees to it gets 9 % of its normal irradiance), or its exact cosine
    convolution ("exact", ``render.envmap.irradiance_table``, by FFT along the map's rows,
    12 ms). Measured together with ``diffuse``, above."""
    indirect: Switch = "auto"
    """Indirect-light net mixed in by the occlusion probability; it follows ``occlusion``
    unless "off" (there is no occlusion probability to mix it in without the occlusion net)."""
    occlusion: Switch = "auto"
    """Occlusion net + Open3D ray-cast targets. "auto": on until ``decide_at``; then the
    carved surface is extracted and the training cameras' reflected view rays are cast at it;
    kept iff at least ``self_occlusion_min`` of them hit the object, else dropped and
    re-measured every ``loss.occlusion_every`` steps until ``decide_until`` (fresh nets if it
    rises above)."""
    decide_at: float = 0.4
    """Fraction of ``iters`` at which "auto" first measures the self-occlusion, once the coarse
    grid has carved: at 0.2 of the preview the gold sphere was still a bumpy blob (radius
    0.52–0.84 for 0.585) and 2.2 % of its reflected rays hit it; at 0.47, 0.19 %."""
    self_occlusion_min: float = 0.005
    """Fraction of reflected view rays hitting the object above which "auto" turns the
    occlusion/indirect model on (``adaptive.SELF_OCCLUSION_MIN``)."""
    decide_until: float = 0.75
    """Fraction of ``iters`` after which an "auto" occlusion that measured off stays off."""
    decide_rays: int = 16384
    """View rays cast at the surface for the self-occlusion measurement."""
    occlusion_offset: float = 1.0
    """Start of the target rays above the surface, in mean edge lengths of the extracted mesh."""
    occlusion_t_near: float = 2.0
    """Hits closer than this many mean edge lengths are ignored (the facet the ray left)."""
    occlusion_smooth: int = 0
    """Taubin smoothing iterations of the extracted mesh before casting (0 = none)."""
    metallic: Switch = "auto"
    background: Literal["auto", "distant", "alpha", "near"] = "auto"
    """distant: background pixel = env radiance along the ray; alpha: composite on the known
    background colour (images with alpha, or "auto" on images whose border is one colour);
    near: a low-resolution field outside the region of interest
    (:mod:`voxnero.fields.background`) in front of the env map, "auto" when the views disagree
    on the colour of the same background direction (parallax: the background is not at
    infinity, :mod:`voxnero.data.distant`)."""
    near_res: int = 48
    """Corners per axis of the near-background grid over the contracted space ``[-2, 2]³``."""
    near_samples: int = 16
    """Samples per ray of the near background (uniform in disparity)."""
    near_far_ratio: float = 64.0
    """Last near-background sample depth over the first; beyond, the env map."""
    near_lr: float = 3e-2
    """Adam learning rate of the near-background grid."""
    exposure: Switch = "auto"
    """A gain per training photo and colour channel (exposure and white balance,
    :mod:`voxnero.fields.exposure`). "auto": measured after the coarse stage, from how far each
    photo's well-exposed pixels sit from the coarse model's renders (one median ratio per photo
    and channel); on iff the spread over the photos reaches ``exposure_min_spread`` and the
    object's and the background's ratios agree (``exposure_min_agreement``); the gains then
    start from the measured ratios (:mod:`voxnero.shape.exposure`). Without a coarse stage
    "auto" is off (a sphere start of a race takes the coarse start's decision)."""
    exposure_min_spread: float = 0.05
    """Standard deviation over the photos of the measured log gain above which "auto" turns the
    gains on (0.05: ±5 % from photo to photo)."""
    exposure_min_agreement: float = 0.3
    """Correlation over the photos between the gains measured on the object's pixels and on the
    background's, at or above which "auto" turns the gains on (an exposure scales a whole photo;
    a misfit of the object's reflections does not reach the background). Measured after the
    preview's coarse stage: dtu_scan97 0.47 (spread 0.112: on); the chrome knot -0.04 (spread
    0.085), bowl_silver 0.48 (spread 0.039), frame_red -0.19 (0.039): off (docs/STAGE1.md,
    finding 20)."""
    exposure_pixels: int = 1024
    """Pixels per photo rendered for the exposure measurement."""
    exposure_lr: float = 1e-2
    """Adam learning rate of the per-photo log gains."""
    hidden: int = 32
    init_roughness: float = 0.4
    """Perceptual roughness the material head outputs before training (everywhere). A rough
    start lets blur absorb the normal error of the early, coarse surface; a mirror can then
    stay rough (two_spheres 256², seed 1: roughness 0.53 on the mirror, Chamfer 0.024). A
    near-specular start (0.1) removed that on the pair but left lone mirrors lumpy
    (sphere_gold preview 0.0116 → 0.070): docs/STAGE1.md, finding 14."""
    init_roughness_candidates: list[float] = field(default_factory=list)
    """Other starting roughnesses raced from the kept initial radius (complete runs, after the
    race of radii); the start that fits the photos best is kept.
    [] (default) = ``init_roughness`` only. One start rarely serves every object: a rough start
    can leave a mirror rough for good, a near-specular one leaves a lone mirror lumpy
    (docs/STAGE1.md, finding 15)."""


@dataclass
class LossConfig:
    """Loss weights."""

    RANGES: ClassVar[dict[str, Range]] = {
        "charbonnier_eps": positive(1.0), "eikonal": WEIGHT, "laplacian": WEIGHT,
        "normal_smooth": WEIGHT, "normal_smooth_radius": Range(0.0, 16.0),
        "normal_smooth_start": FRACTION, "occlusion": WEIGHT, "occlusion_start": FRACTION,
        "occlusion_every": at_least(1)}

    charbonnier_eps: float = 1e-3
    color_space: Literal["srgb", "linear"] = "srgb"
    eikonal: float = 0.1
    laplacian: float = 1e-4
    """Weight of the squared Laplacian of the SDF grid (mean over voxels, in voxel units)."""
    normal_smooth: float = 0.02
    """Weight of the normal smoothness between surface points and points jittered by
    ``normal_smooth_radius`` voxels of the first grid (0 = off)."""
    normal_smooth_radius: float = 1.0
    normal_smooth_start: float = 0.0
    """Fraction of ``iters`` before which the normal smoothness is off (let the topology form:
    it resisted carving the torus' hole)."""
    occlusion: float = 1.0
    occlusion_start: float = 0.2
    """Fraction of ``iters`` after which occlusion targets are computed and used."""
    occlusion_every: int = 200
    """Steps between rebuilds of the Open3D surface for the occlusion targets."""


@dataclass
class OptimConfig:
    """Adam learning rates per parameter group and decay."""

    RANGES: ClassVar[dict[str, Range]] = {
        "lr_sdf": LEARNING_RATE, "lr_feat": LEARNING_RATE, "lr_heads": LEARNING_RATE,
        "lr_env": LEARNING_RATE, "lr_light": LEARNING_RATE, "decay": FRACTION,
        "warmup": at_least(0)}

    lr_sdf: float = 1e-2
    lr_feat: float = 1e-2
    lr_heads: float = 3e-3
    lr_env: float = 3e-2
    lr_light: float = 3e-3
    decay: float = 0.1
    """Final learning rate as a fraction of the initial (cosine decay over ``iters``)."""
    warmup: int = 50
    lr_sdf_per_voxel: bool = True
    """Scale the SDF learning rate with the voxel size at each upsampling (×48/96 for
    48³ → 96³). Adam steps every voxel by about lr, so a fixed lr leaves bumps of the same height
    on a finer grid, i.e. steeper ones: normal noise. Measured on sphere_gold (docs/STAGE1.md)."""


@dataclass
class ShapeConfig:
    """Stage 1: SDF geometry (and rough materials/lights) from posed photos."""

    RANGES: ClassVar[dict[str, Range]] = {
        "iters": at_least(1, BIG_COUNT), "seed": SEED, "mesh_res": at_least(8, 1024),
        "eval_mesh_res": at_least(8, 1024, also=(0,)), "fit_rays": at_least(1, BIG_COUNT),
        "race_cut": Range(0.0, 100.0), "race_cut_at": Range(0.0, 1.0, lo_open=True, hi_open=True),
        "ckpt_every_s": Range(0.0), "preview_every": at_least(0), "eval_every_s": Range(0.0),
        "threads": THREADS, "radius": positive(), "center": Range(), "bbox": Range()}
    """Allowed values; every section's table is checked before ``validate`` (and so before a
    command reads its scene)."""
    FREE_ON_RESUME: ClassVar[tuple[str, ...]] = (
        "threads", "mesh_res", "eval_mesh_res", "fit_rays", "race_cut", "race_cut_at",
        "ckpt_every_s", "preview_every", "eval_every_s")
    """Keys a resume may change (outputs, logging, cadence, judging a finished race); any other
    key shapes the model, and a checkpoint trained with another value is refused
    (:mod:`voxnero.safety.fingerprint`)."""
    RETIRED: ClassVar[dict[str, object]] = {"grid.init_trial": 1.0}
    """Settings removed from the config, with the value every run had that is still possible:
    kept in the fingerprint so that checkpoints written before the removal resume
    (``grid.init_trial`` < 1 was the removed first look; 1 is the race)."""

    iters: int = 1500
    seed: int = 0
    grid: GridConfig = field(default_factory=GridConfig)
    coarse: CoarseConfig = field(default_factory=CoarseConfig)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    neus: NeusConfig = field(default_factory=NeusConfig)
    light: LightConfig = field(default_factory=LightConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    mesh_res: int = 192
    """Resolution of the grid resampling used for the final marching cubes; where that mesh's
    genus differs from the field refined by 2 (``2·(n − 1) + 1`` samples, a resampling that
    opened or closed a handle at a pinched wall), the refined mesh is written instead
    (:func:`voxnero.shape.run_files.final_mesh`)."""
    eval_mesh_res: int = 0
    """Marching-cubes resolution of the periodic Chamfer evaluations (0 = the grid's own)."""
    fit_rays: int = 16384
    """Training pixels (fixed seed) on which a race of initial radii compares the final fits."""
    race_cut: float = 0.0
    """dB: a start of a race whose fit (on the ``fit_rays`` pixels) is more than this behind the
    best finished start's at ``race_cut_at`` of its steps stops there and loses (0 = off: every
    start runs to its end). It only drops a clear loser, it never picks a winner early (an
    early winner was finding 13's mistake). `preview` and `standard` 3: on the corpus and the
    dev scenes a sphere start gained at most 1.70 dB (`preview`) and 1.34 dB (`standard`) from
    half its steps to its end, an opened start at most 1.19 dB (`standard`); the starts more
    than 3 dB behind there (five scenes at `preview`, seven at `standard`) stop, and no race
    changes (docs/STAGE1.md finding 52). `quality` 0: not measured. A resume may change it."""
    race_cut_at: float = 0.5
    """Fraction of a start's ``iters`` at which ``race_cut`` is judged (once)."""
    ckpt_every_s: float = 60.0
    preview_every: int = 500
    eval_every_s: float = 60.0
    """Seconds of training between Chamfer evaluations (scenes with GT only; 0 = never)."""
    bbox: list[float] | None = None
    """Region of interest ``[xmin, ymin, zmin, xmax, ymax, zmax]`` in the scene's input frame
    (None: the format's own, see :mod:`voxnero.data.scene`); wins over ``center``/``radius``."""
    center: list[float] | None = None
    """Centre ``[x, y, z]`` of a spherical region of interest (input frame)."""
    radius: float | None = None
    """Radius of the region of interest (input frame units)."""
    use_masks: bool = False
    """Train with the capture's object masks as alpha (NeuS/IDR captures with ``mask/``).
    Off by default: the NeRO setting has no masks; they are evaluation data."""
    threads: int = 1
    """torch CPU threads (0 = torch's default). On the shared 2-core dev machine one thread was
    2.5× faster than two under contention (docs/BENCHMARKS.md); raise it on a dedicated machine."""

    def validate(self) -> None:
        """Check cross-field consistency (single values are checked against ``RANGES`` before);
        raise :class:`ConfigError` with the fix."""
        g = self.grid
        if len(g.upsample_at) != len(g.res) - 1:
            raise ConfigError(f"shape.grid.upsample_at has {len(g.upsample_at)} values for "
                              f"{len(g.res)} resolutions",
                              fix="give one fraction of iters per resolution change")
        if self.sampling.coarse_keep > self.sampling.coarse:
            raise ConfigError("shape.sampling.coarse_keep must be <= shape.sampling.coarse")
        if 0 < self.sampling.coarse_final < self.sampling.coarse_keep:
            raise ConfigError("shape.sampling.coarse_final must be 0 (off) or >= "
                              "shape.sampling.coarse_keep")
        rc = self.light.init_roughness_candidates
        if any(not 0.02 < r < 1.0 for r in [self.light.init_roughness, *rc]):
            raise ConfigError(f"shape.light.init_roughness={self.light.init_roughness} and its "
                              f"candidates {rc} must lie in (0.02, 1) (0.02: the material "
                              "head's smallest roughness)",
                              fix="give perceptual roughnesses such as 0.1 or 0.4")
