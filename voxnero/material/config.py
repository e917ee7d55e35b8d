"""Configuration of stage 2 (``voxnero material``): one small dataclass per component.

Presets set these in the ``material:`` section of ``voxnero/configs/<preset>.yaml``; every key
can be overridden on the command line (``iters=800``, ``render.spp_ggx=16``, ``field.kind=grid``).
"""

from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as _field
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
class FieldConfig:
    """Material field over the fixed surface: albedo, metallic, roughness."""

    RANGES: ClassVar[dict[str, Range]] = {
        "grid_res": at_least(2, 1024), "smooth": WEIGHT, "init_albedo": FRACTION,
        "init_metallic": FRACTION, "init_roughness": FRACTION, "residual_l2": WEIGHT,
        "range_prior": WEIGHT, "split_at": Range(0.0, 1.0), "split_distance": Range(0.0, 2.0),
        "split_min_fraction": Range(0.0, 0.5), "split_metallic": Range(0.0, 1.0, lo_open=True),
        "race_steps": at_least(1, BIG_COUNT), "relabel_at": FRACTION,
        "probe_steps": at_least(0, BIG_COUNT)}

    kind: Literal["vertex", "grid"] = "vertex"
    """vertex: parameters per mesh vertex, barycentric interpolation, smoothness over mesh edges;
    grid: dense trilinear grid over the unit cube, smoothness over neighbouring cells."""
    grid_res: int = 48
    """Grid resolution (kind: grid)."""
    smooth: float = 0.2
    """Weight of the smoothness regulariser (mean penalty of neighbour differences)."""
    smooth_norm: Literal["l2", "l1"] = "l1"
    """How the smoothness measures a neighbour difference (``voxnero.material.field``).
    "l1" (total variation of the raw values): a material that changes pays per edge crossed,
    however slowly it ramps, so the albedo can no longer imitate shading the light gets wrong
    (the table's 8-bit photos clip its ceiling panels: its albedo grew 20-30 % on the faces they
    light and the Mitsuba relight gap was 7.2 / 4.1 dB; 3.0 / 1.8 with "l1" at 0.05, 1.5 / 0.9
    at 0.2). Before the two-material split (session 20), 0.2 merged the corpus bunny's copper
    and terracotta halves (5.3 -> 10.2 dB), so 0.05 was the default then (docs/BENCHMARKS.md
    sessions 19, 20). "l2" (until session 19): squares of the activated values, under which a
    slow ramp over n edges costs J²/n."""
    init_albedo: float = 0.5
    init_metallic: float = 0.0
    """Start of metalness. 0: every surface starts a dielectric and a metal climbs (the copper
    half of the corpus bunny reaches 0.94, the chrome knot 0.99). From 0.5, the ridge between the
    two, rough dielectrics under an uncertain light fell to the metal side (chair, duck:
    metallic 1, roughness 0.85-0.89, 12-13 dB lost in the Mitsuba relight check; session 18)."""
    init_roughness: float = 0.4
    residual_l2: float = 1e-3
    """Weight of the L2 penalty on the spatial residual (raw units) over the global base."""
    range_prior: float = 1e-3
    """Weak pull of metallic toward 0 or 1 (m (1 − m)) and of every raw value toward 0."""
    regions: Literal["auto", "one"] = "auto"
    """One material or two (kind: vertex). "auto": at ``split_at`` of the steps the vertices'
    albedo chromaticity and roughness after a probe (``probe_steps``) are split by two-means
    (:mod:`voxnero.material.regions`); if the two centres lie ``split_distance`` apart and the
    smaller holds ``split_min_fraction`` of the vertices, each gets its own base, every
    triangle is one of the two, and both restart metalness at ``split_metallic``. Under
    one shared base the corpus bunny's terracotta half followed its copper half into a rough
    metal (metallic 0.96; docs/STAGE2.md, session 20). Logged and written to materials.json.
    "one": never split."""
    probe_steps: int = 100
    """Steps of the throw-away probe whose per-vertex materials ``regions`` = auto splits
    (smoothness off, light held; ``MaterialTrainer._probe_features``); 0: the current ones."""
    split_at: float = 0.15
    """Fraction of ``iters`` at which ``regions`` and ``metal`` decide."""
    split_distance: float = 0.06
    """Distance of the two clusters' centres (albedo chromaticity and roughness,
    ``regions.material_features``) from which they are two materials. Measured after the
    probe: the corpus bunny's copper and terracotta halves 0.10 apart, the one-material oak
    table (whose albedo under its clipped panels is brighter, not another hue) 0.02."""
    split_min_fraction: float = 0.1
    """Share of the vertices the smaller cluster must hold."""
    split_metallic: float = 0.05
    """Metalness both materials restart from after a split when ``metal`` = free (the
    dielectric side, as ``init_metallic``, but not so deep in the sigmoid that a metal cannot
    climb back in the steps left)."""
    metal: Literal["race", "free"] = "race"
    """Metalness per material (kind: vertex). "race": at ``split_at``, every assignment of
    dielectric / metal to the materials trains ``race_steps`` steps with it held; the lowest
    object loss wins and stays held (0 or 1) for the rest of the run; logged with each
    candidate's loss and written to materials.json. "free": learned per vertex as any channel
    (the corpus bunny's terracotta half then followed the copper half into a rough metal and
    climbed back from 0.05 after a split: the dielectric basin is better, 24.8 against 24.0 dB
    on the training photos, but out of reach by gradient; docs/STAGE2.md, session 20)."""
    relabel_at: list[float] = _field(default_factory=lambda: [0.5, 0.75])
    """Fractions of ``iters`` at which the boundary of a split field is placed by the photos
    (``MaterialTrainer.relabel_boundary``): each triangle along it takes the material that
    renders its pixels better. The two-means labels put it where the learned values cross,
    which on the corpus bunny cost 1.6 dB in the Mitsuba relight check against the true
    boundary even with the true materials on both sides (docs/STAGE2.md, session 20)."""
    race_steps: int = 150
    """Steps each candidate of the metalness race trains (the winner's count toward
    ``iters``; the others are the race's cost)."""


@dataclass
class LightConfig:
    """Direct light (explicit lat-long HDR map) and indirect light."""

    RANGES: ClassVar[dict[str, Range]] = {
        "env_height": at_least(4, 4096), "upsample_at": FRACTION, "env_smooth": WEIGHT,
        "update_smooth": Range(0.0, 16.0),
        "bounces": at_least(0, 16), "rr_bounces": at_least(0, 16),
        "rr_survive": Range(0.0, 1.0, lo_open=True), "bounce_spp": at_least(1, 64)}

    env_height: list[int] = _field(default_factory=lambda: [64, 256])
    """Env-map heights coarse to fine (width = 2 × height); upsampled at ``upsample_at``."""
    upsample_at: float = 0.3
    """Fraction of ``iters`` at which the env map moves to the next resolution."""
    indirect: Literal["auto", "traced", "splitsum", "off"] = "auto"
    """Radiance of secondary rays that hit the object. traced: the ray is cast on the mesh and
    the hit shaded with the current material and env map by the same estimator (``bounces``
    bounces, then ``rr_bounces`` by Russian roulette, then the split-sum estimate); splitsum:
    the split-sum estimate of the outgoing radiance at the first hit (no further bounce); off:
    black. auto: traced when at least 8 % of the cache's cosine secondary rays hit the mesh
    (``trainer.TRACED_HIT_MIN``: objects that see much of themselves), splitsum from 0.1 %
    (``trainer.SECONDARY_HIT_MIN``), else off."""
    bounces: int = 2
    """Inter-reflection bounces traced after the primary hit (indirect: traced). Two: a chrome
    object that sees itself shows reflections of reflections (docs/STAGE2.md)."""
    rr_bounces: int = 2
    """Further bounces, each continued with probability ``rr_survive`` (Russian roulette)."""
    rr_survive: float = 0.5
    bounce_spp: int = 1
    """Samples per strategy (cosine, GGX, env) at every secondary hit."""
    env_smooth: float = 1e-4
    """Weight of a total-variation prior on the log env map (fills directions never seen)."""
    update_smooth: float = 1.0
    """Gaussian sigma (pixels of the current map) of each Adam step of the log env map on the
    cells no background pixel sees: there the map moves by ``blur(new - old)``. Those cells are
    learned only through the object's Monte Carlo shading, a sparse and noisy gradient that
    Adam turns into full-size steps (speckle in a mirror's sky, over a room's lamps); the
    blur spreads each step over neighbours. Cells the photos see keep plain steps (blurring
    them too slowed the sharp background: −2.6 dB on sphere_gold's test views). 0 = plain.
    Measured in docs/BENCHMARKS.md, session 11."""


@dataclass
class RenderConfig:
    """Monte Carlo rendering equation on the surface."""

    RANGES: ClassVar[dict[str, Range]] = {
        "spp_cos": at_least(0, 4096), "spp_ggx": at_least(0, 4096), "spp_env": at_least(0, 4096),
        "eval_scale": at_least(1, 1024), "eval_subpixels": at_least(1, 1024),
        "linearise_after": Range(0.0, 1.0)}

    spp_cos: int = 4
    """Cosine-weighted samples per pixel and estimate (training)."""
    spp_ggx: int = 4
    """GGX visible-normal samples per pixel and estimate (training)."""
    spp_env: int = 4
    """Env-map importance samples per pixel and estimate (training)."""
    eval_scale: int = 8
    """Evaluation renders use ``eval_scale`` times the training samples (32 per strategy: a
    quick look that reads 1-2 dB under ``voxnero eval``'s 128, whose renders have converged to
    0.3 dB; docs/BENCHMARKS.md, session 11)."""
    eval_subpixels: int = 16
    """Evaluation renders average this many stratified points per pixel (the box filter of the
    photos; the samples are split among them, 1 = pixel centres)."""
    decorrelate: bool = True
    """Loss on two independent estimates per pixel, (p1 − t)(p2 − t), instead of (p − t)²:
    no Monte Carlo variance term in the expected loss (costs twice the samples)."""
    linearise_after: float = 0.5
    """With ``decorrelate``: from this fraction of ``iters`` on, the sRGB error linearised at
    the photo's value, g'(t)² (p1 − t)(p2 − t) in linear radiance (g the sRGB encoding),
    replaces (g(p1) − g(t))(g(p2) − g(t)) (1 = never). Both weight dark pixels as the 8-bit
    photos do, but only the linearised one is unbiased at the optimum: g is concave, so
    E g(p) < g(E p), a noisy estimate reads darker, and the fit repays it with a brighter albedo
    and a smoother (less noisy) lobe (corpus mug: blue albedo 0.78 for 0.60, roughness 0.013
    for 0.1). Far from the optimum the linearised weights are not the sRGB error's (linearised
    from the first step the corpus duck became a rough metal), so training starts in sRGB
    (docs/STAGE2.md, docs/BENCHMARKS.md session 12)."""
    hold_brdf: bool = False
    """Before ``linearise_after``: metallic and roughness stay at their start values (their
    gradients are zeroed) while albedo and light fit; after it all of them learn. It keeps the
    sRGB phase from driving a dielectric's roughness to the floor (mug 0.076 for 0.1 with
    ``linearise_after`` = 0.25), but the map learned meanwhile to suit the held material costs
    a chrome object more than 1 dB, so it is off (docs/BENCHMARKS.md session 12)."""
    visibility: Switch = "auto"
    """Cast every secondary ray against the mesh (shadows / indirect). "auto": only when at
    least 0.1 % of cosine rays from the surface hit it (``trainer.SECONDARY_HIT_MIN``; a convex
    object never shadows itself, and its marching-cubes mesh measures 0–0.07 %); "on" / true:
    always; "off" / false: never."""
    jitter: bool = True
    """Training renders each object pixel through a random point of its footprint, re-cast on
    the mesh (the photos are box-filtered over the pixel); False shades the cached centre hit."""
    diffuse: Literal["principled", "weighted"] = "principled"
    """The BRDF's diffuse lobe (``voxnero.render.brdf``): "principled" = the Disney diffuse with
    retro-reflection of Mitsuba's ``principled`` BSDF (Burley's fit to measured materials),
    which rendered the dev scenes and the corpus; "weighted" = Lambert energy-weighted under
    the specular interface (glTF's ``fresnel_mix``; stage 1's default). With the TRUE
    mesh, material and map the photos are 1.01x our "principled" render and 1.08x the
    "weighted" one (oak table). Together with ``field.init_metallic`` = 0 it narrows the
    Mitsuba relight gap of the dielectrics (table 8.97 -> 7.23 dB, chair 5.97 -> 4.14, duck
    1.97 -> 1.38; corpus metals within 0.16 dB, the dev gold sphere 0.11 / 0.34 dB worse;
    docs/STAGE2.md, session 18).
    Written to the asset's sidecar, so that ``voxnero relight`` and ``voxnero eval`` render the
    asset as it was fitted."""


@dataclass
class NormalsConfig:
    """Shading normals learned on the fixed mesh (:mod:`voxnero.material.normals`)."""

    RANGES: ClassVar[dict[str, Range]] = {
        "lr": LEARNING_RATE, "rounds": at_least(0, 256), "prior": WEIGHT,
        "start": Range(0.0, 1.0)}

    refine: bool = False
    """Learn the vertex normals (positions stay; the exports carry the learned ones). Stage 1's
    normals are a few degrees off, which a mirror's reflections show and a fixed normal makes
    the fit blur with roughness: the knot's ``standard`` mesh with the TRUE normals relights at
    25.7 dB instead of 20.1 (roughness 0.05 for 0.03 instead of 0.16). Learned from the photos
    the normals do not get there: at ``lr`` 2e-3 the knot's training fit gained 0.35 dB and its
    test views 0.38 dB, its normal error went 2.70° -> 2.63°, and it relit 0.3 dB worse (mug:
    −0.06 dB); at 1e-2 and 3e-2 the Monte Carlo gradients made the normals noisy and the fit
    worse (docs/BENCHMARKS.md, session 25). So it is off: a user with a mirror may try it."""
    lr: float = 2e-3
    """Adam learning rate of the normals' parameters (decays with ``lr_decay``)."""
    rounds: int = 8
    """Neighbour-averaging rounds from the parameters to the correction (its smoothness along
    the surface, in edges)."""
    prior: float = 1e-3
    """Weight of ``mean |n − n0|²`` (squared chord to stage 1's normal)."""
    start: float = 0.3
    """Fraction of ``iters`` from which the normals learn: after the materials' decisions
    (``field.split_at`` and the metalness race) and the env map's upsampling, so that they do
    not bend to explain a light or a material still far off."""


@dataclass
class MaterialConfig:
    """Stage 2: materials and lights on a fixed mesh."""

    RANGES: ClassVar[dict[str, Range]] = {
        "iters": at_least(0, BIG_COUNT), "batch": at_least(1, BIG_COUNT),
        "bg_batch": at_least(0, BIG_COUNT), "lr_material": LEARNING_RATE,
        "lr_env": LEARNING_RATE, "lr_decay": positive(1.0),
        "max_pixels": at_least(1, BIG_COUNT), "max_bg_pixels": at_least(0, BIG_COUNT, also=(-1,)),
        "seed": SEED, "threads": THREADS, "texture_size": at_least(16, 16384),
        "eval_views": at_least(0, also=(-1,)), "checkpoint_every": at_least(0),
        "log_every": at_least(1)}
    """Allowed values (:func:`voxnero.config.check_numbers`), checked before ``validate``;
    ``lr_decay`` > 0: it is raised to a power (0 would stop training at the first step)."""
    FREE_ON_RESUME: ClassVar[tuple[str, ...]] = (
        "threads", "texture_size", "eval_views", "checkpoint_every", "log_every",
        "render.eval_scale", "render.eval_subpixels")
    """Keys a resume may change (exports, evaluation, logging, cadence); any other key shapes
    the model, and a checkpoint trained with another value is refused
    (:mod:`voxnero.safety.fingerprint`)."""

    iters: int = 2000
    """Training steps. 2000, not 1000: the env map, i.e. the whole image's background, is still
    converging at 1000 (sphere_gold: background PSNR 35.8 -> 37.5 dB, 16-view novel views
    30.03 -> 30.20 dB; docs/STAGE2.md)."""
    batch: int = 1024
    """Object pixels per step."""
    bg_batch: int = 16384
    """Background pixels per step (they train the env map directly)."""
    lr_material: float = 0.05
    lr_env: float = 0.03
    lr_decay: float = 0.1
    """Final learning rate as a fraction of the initial one (exponential decay)."""
    max_pixels: int = 400000
    """At most this many object pixels are cached (a random subset of all training pixels)."""
    max_bg_pixels: int = -1
    """At most this many background pixels are cached (-1 = all)."""
    seed: int = 0
    threads: int = 1
    """torch CPU threads (0 = torch's default). 1 by default: the batches are small and on the
    shared 2-core CPU torch's default threading made a step ~6x slower."""
    field: FieldConfig = _field(default_factory=FieldConfig)
    light: LightConfig = _field(default_factory=LightConfig)
    render: RenderConfig = _field(default_factory=RenderConfig)
    normals: NormalsConfig = _field(default_factory=NormalsConfig)
    texture_size: int = 1024
    """Side of the exported albedo / metallic-roughness textures (pixels)."""
    eval_views: int = -1
    """Test views rendered for the metrics at the end (-1 = all, 0 = none)."""
    checkpoint_every: int = 300
    log_every: int = 50

    def validate(self) -> None:
        """Check what ``RANGES`` cannot (single values are checked before); raise ConfigError
        naming the key and the fix."""
        r = self.render
        if r.spp_cos + r.spp_ggx + r.spp_env < 1:
            raise ConfigError("material.render.spp_* must give at least one sample",
                              fix="e.g. render.spp_cos=8 render.spp_ggx=8")
        if not self.light.env_height:
            raise ConfigError("material.light.env_height=[] needs at least one height",
                              fix="e.g. light.env_height=[64,128]")
