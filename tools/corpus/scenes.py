"""The corpus: ten objects chosen to cover what the dev scenes (a sphere, a torus) do not.

| need (corpus issue)                | scenes                                                  |
|------------------------------------|---------------------------------------------------------|
| thin parts a few pixels wide       | table_oak (legs 0.05 ≈ 5 px), chair_green, knot_chrome  |
| holes, genus ≥ 2                   | pretzel_steel 3, frame_red 5, gear_brass 5, chair_green 3 |
| concavities                        | bowl_silver, mug_glaze                                  |
| flat faces with sharp edges        | table_oak, frame_red, gear_brass                        |
| metal and dielectric on one object | bunny_copper_clay                                       |
| mirror (roughness ≤ 0.05)          | knot_chrome (0.03), bowl_silver (0.05)                  |
| rough (≥ 0.5)                      | table_oak, frame_red, chair_green, bunny's clay         |
| small bright sun (≥ 10⁴ : 1)       | sky_noon, sky_low: knot, frame, bunny                   |
| indoor environments                | room_a, room_b, warehouse: pretzel, table, gear, mug, chair |
| views from below, straight above   | rigs ``full`` (to -65°), ``rings`` (to -40°, one at 90°) |
| objects filling 30 % and 80 %      | duck_small (30 %), table_oak and mug_glaze (80 %)       |

Materials are Mitsuba ``principled`` parameters (linear base colour, metallic, roughness;
GGX alpha = roughness²). A scene with two materials splits its mesh at a height: faces whose
centroid lies above ``split_z`` get the second material.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from tools.corpus import shapes


@dataclass(frozen=True)
class Material:
    """Mitsuba ``principled`` parameters (specular 0.5: dielectric F0 0.04)."""

    name: str
    base_color: tuple[float, float, float]
    metallic: float
    roughness: float


@dataclass(frozen=True)
class SceneSpec:
    """One corpus scene: the shape, its material(s), the lights and the cameras."""

    name: str
    shape: Callable[[], shapes.Mesh]
    source: str
    materials: tuple[Material, ...]
    env: str
    relight: tuple[str, str]
    rig: str = "band"
    fill: float = 0.63
    split_z: float | None = None
    covers: tuple[str, ...] = field(default_factory=tuple)


def _sdf(make: Callable[[], shapes.SDF], res: int = 256) -> Callable[[], shapes.Mesh]:
    return lambda: shapes.mesh_sdf(make(), res)


PROCEDURAL = "procedural signed distance of this tool (tools/corpus/shapes.py), CC0"
CHROME = Material("chrome", (0.95, 0.95, 0.95), 1.0, 0.03)

SCENES: tuple[SceneSpec, ...] = (
    SceneSpec("knot_chrome", _sdf(shapes.torus_knot), PROCEDURAL + ": (2,3) torus knot tube",
              (CHROME,), "sky_noon", ("room_a", "venice_sunset"), rig="full",
              covers=("mirror", "self-reflection", "thin tube", "sun", "genus 1")),
    SceneSpec("pretzel_steel", _sdf(shapes.pretzel), PROCEDURAL + ": three merged rings",
              (Material("steel", (0.78, 0.78, 0.8), 1.0, 0.2),), "warehouse",
              ("sky_low", "proc_courtyard"), rig="rings",
              covers=("genus 3", "holes", "indoor", "straight above")),
    SceneSpec("table_oak", _sdf(shapes.table), PROCEDURAL + ": table, legs 0.05 wide",
              (Material("oak", (0.45, 0.28, 0.14), 0.0, 0.55),), "room_a",
              ("venice_sunset", "sky_noon"), fill=0.8,
              covers=("thin legs", "flat faces", "sharp edges", "rough", "indoor", "80 %")),
    SceneSpec("frame_red", _sdf(shapes.frame_cube), PROCEDURAL + ": cube with three tunnels",
              (Material("red paint", (0.6, 0.05, 0.04), 0.0, 0.6),), "sky_low",
              ("warehouse", "room_b"), rig="rings",
              covers=("genus 5", "flat faces", "sharp edges", "rough", "sun")),
    SceneSpec("bowl_silver", _sdf(shapes.bowl), PROCEDURAL + ": bowl on a ring foot",
              (Material("silver", (0.97, 0.96, 0.91), 1.0, 0.05),), "venice_sunset",
              ("room_a", "proc_courtyard"), rig="full",
              covers=("mirror", "concavity", "self-reflection", "views from below")),
    SceneSpec("gear_brass", _sdf(shapes.gear), PROCEDURAL + ": gear with holes",
              (Material("brass", (0.91, 0.78, 0.42), 1.0, 0.3),), "room_b",
              ("sky_noon", "proc_courtyard"), rig="rings",
              covers=("genus 5", "flat faces", "sharp edges", "indoor")),
    SceneSpec("bunny_copper_clay",
              lambda: shapes.package_mesh("bunny.obj", up="y", subdivide=2),
              "pybullet_data/bunny.obj (pybullet 3.2.7, zlib licence; low-poly Stanford bunny, "
              "Stanford 3D Scanning Repository), Loop-subdivided twice",
              (Material("terracotta", (0.55, 0.22, 0.12), 0.0, 0.7),
               Material("copper", (0.95, 0.64, 0.54), 1.0, 0.25)),
              "sky_noon", ("warehouse", "room_b"), split_z=-0.05,
              covers=("metal + dielectric", "rough", "sun", "outdoor")),
    SceneSpec("duck_small",
              lambda: shapes.package_mesh("duck.obj", up="y", remesh_res=256),
              "pybullet_data/duck.obj (pybullet 3.2.7, zlib licence; the COLLADA sample duck), "
              "made watertight by marching cubes of its signed distance",
              (Material("yellow plastic", (0.8, 0.55, 0.05), 0.0, 0.2),), "proc_courtyard",
              ("venice_sunset", "room_a"), rig="rings", fill=0.3,
              covers=("30 % of the frame", "glossy dielectric")),
    SceneSpec("mug_glaze", _sdf(shapes.mug), PROCEDURAL + ": mug with a handle",
              (Material("blue glaze", (0.1, 0.25, 0.6), 0.0, 0.1),), "warehouse",
              ("sky_low", "proc_courtyard"), rig="full", fill=0.8,
              covers=("concavity", "handle (genus 1)", "80 %", "indoor")),
    SceneSpec("chair_green", _sdf(shapes.chair), PROCEDURAL + ": chair of rods",
              (Material("green paint", (0.1, 0.35, 0.12), 0.0, 0.5),), "room_b",
              ("sky_low", "venice_sunset"), rig="full",
              covers=("thin rods", "genus 3", "rough", "indoor", "views from below")),
)

HELDOUT: tuple[SceneSpec, ...] = (
    SceneSpec("cow_ivory", _sdf(shapes.cow),
              PROCEDURAL + ": stylised cow, horns and tail 3 px wide",
              (Material("ivory glaze", (0.8, 0.74, 0.62), 0.0, 0.3),), "warehouse",
              ("room_b", "sky_noon"), rig="full",
              covers=("thin legs", "horns", "glossy dielectric", "indoor", "views from below")),
    SceneSpec("vase_pewter", _sdf(shapes.vase), PROCEDURAL + ": vase with a narrow open neck",
              (Material("pewter", (0.68, 0.67, 0.64), 1.0, 0.35),), "room_a",
              ("sky_low", "proc_courtyard"),
              covers=("concavity behind a narrow opening", "rough metal", "indoor")),
    SceneSpec("teapot_alu", _sdf(shapes.teapot), PROCEDURAL + ": teapot with spout and handle",
              (Material("aluminium", (0.91, 0.92, 0.92), 1.0, 0.25),), "proc_courtyard",
              ("room_a", "warehouse"), rig="rings",
              covers=("smooth metal", "handle (genus 1)", "spout", "outdoor")),
    # built in session 51, after preview's hull growth (finding 55) was chosen: never tuned on
    SceneSpec("ladle_steel", _sdf(shapes.ladle), PROCEDURAL + ": ladle, a shallow dish",
              (Material("polished steel", (0.8, 0.8, 0.82), 1.0, 0.12),), "venice_sunset",
              ("room_b", "sky_low"), rig="full",
              covers=("shallow concavity", "smooth metal", "thin handle", "views from below")),
    SceneSpec("hammer_oak_iron", _sdf(shapes.hammer), PROCEDURAL + ": hammer, head and handle",
              (Material("oiled oak", (0.5, 0.32, 0.16), 0.0, 0.45),
               Material("iron", (0.56, 0.57, 0.58), 1.0, 0.3)),
              "room_b", ("proc_courtyard", "warehouse"), split_z=0.4, rig="rings",
              covers=("metal + dielectric", "flat faces", "sharp edges", "thin handle",
                      "indoor")),
)
"""Scenes built only to check that what was tuned on ``SCENES`` holds on a shape it never saw
(``--scenes cow_ivory``): not in the corpus, its benches or its medians (docs/CORPUS.md)."""


def by_name(names: list[str] | None) -> list[SceneSpec]:
    """The specs called ``names`` (the corpus's ten when None; held-out ones only by name), in
    the order given."""
    if not names:
        return list(SCENES)
    known = {s.name: s for s in SCENES + HELDOUT}
    missing = [n for n in names if n not in known]
    if missing:
        raise SystemExit(f"unknown corpus scene(s) {missing}; known: {sorted(known)}")
    return [known[n] for n in names]
