"""Tests of ``tools/corpus``: topology, cameras, env-map conventions, ground-truth maps, report.

Everything here runs without Mitsuba (the tools-only extra); the one Mitsuba render is marked
slow and needs ``pip install -e .[scenes]``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tools.corpus import bench, bg_consistency, build, envmaps, rigs, shapes
from tools.corpus.scenes import HELDOUT, SCENES, Material, SceneSpec, by_name
from voxnero.mesh.topology import genus, mesh_topology

# --------------------------------------------------------------------------- shapes / genus

@pytest.mark.parametrize("sdf, res, expected", [
    (shapes.sphere(0.6), 48, 0),
    (shapes.torus(0.5, 0.15), 64, 1),
    (shapes.union(shapes.transformed(shapes.torus(0.3, 0.1), offset=(-0.45, 0, 0)),
                  shapes.transformed(shapes.torus(0.3, 0.1), offset=(0.45, 0, 0))), 96, 2),
    (shapes.pretzel(), 128, 3),
    (shapes.frame_cube(), 96, 5),
    (shapes.teapot(), 96, 1),  # held out: the handle joins the body
    (shapes.vase(), 96, 0),
    (shapes.cow(), 128, 0),  # horns and tail 0.036 wide: one piece with the body
    (shapes.ladle(), 128, 0),  # the dish 0.05 thick: one closed wall (at 96³ pinched, open)
    (shapes.hammer(), 96, 0),  # the claw's notch cuts the head's end, not through the handle
])
def test_genus_of_marching_cubes_meshes(sdf, res, expected):
    m = shapes.mesh_sdf(sdf, res)
    assert genus(m.triangles, len(m.vertices)) == expected


def test_genus_of_an_open_mesh_is_undefined():
    m = shapes.mesh_sdf(shapes.sphere(0.6), 32)
    assert genus(m.triangles[1:], len(m.vertices)) is None


def test_marching_cubes_normals_point_outward():
    m = shapes.mesh_sdf(shapes.sphere(0.6), 48)
    radial = m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
    assert (np.sum(m.normals * radial, axis=1) > 0.95).all()
    assert np.allclose(np.linalg.norm(m.vertices, axis=1), 0.6, atol=0.01)


def test_shape_touching_the_grid_border_is_refused():
    with pytest.raises(ValueError, match="border"):
        shapes.mesh_sdf(shapes.sphere(1.2), 16)


def test_every_corpus_spec_is_consistent():
    names = [s.name for s in SCENES + HELDOUT]
    assert len(SCENES) >= 10 and len(set(names)) == len(names)
    for s in SCENES + HELDOUT:
        assert s.env not in s.relight and len(set(s.relight)) == 2
        assert {s.env, *s.relight} <= set(envmaps.SOURCES)
        assert len(s.materials) == (1 if s.split_z is None else 2)
        assert s.rig in rigs.RIGS and 0.1 < s.fill < 1.0
    rough = [m.roughness for s in SCENES for m in s.materials]
    assert min(rough) <= 0.05 and max(rough) >= 0.5
    assert {0.3, 0.8} <= {s.fill for s in SCENES}


def test_held_out_scenes_are_built_only_by_name():
    assert by_name(None) == list(SCENES)  # the corpus, its benches and medians: never held out
    assert by_name([HELDOUT[0].name, SCENES[0].name]) == [HELDOUT[0], SCENES[0]]
    with pytest.raises(SystemExit, match="unknown corpus scene"):
        by_name(["no_such_scene"])


# --------------------------------------------------------------------------- cameras

@pytest.mark.parametrize("fill", [0.3, 0.63, 0.8])
def test_distance_for_fill_projects_the_sphere_to_that_width(fill):
    radius, width = 0.8, 256
    d = rigs.distance_for_fill(radius, fill)
    c2w = rigs.look_at_gl(np.array([[d, 0.0, 0.0]]))[0]
    f = 0.5 * width / math.tan(math.radians(rigs.FOV_X_DEG) / 2)
    # silhouette circle of the sphere seen from distance d: tangent points
    a = math.asin(radius / d)
    t = np.linspace(0, 2 * math.pi, 361)  # holds 0 and pi: the extremes
    ring = np.stack([np.full_like(t, radius * math.sin(a)),
                     radius * math.cos(a) * np.cos(t), radius * math.cos(a) * np.sin(t)], 1)
    pc = (ring - c2w[:3, 3]) @ c2w[:3, :3]  # world -> OpenGL camera
    u = f * pc[:, 0] / -pc[:, 2]
    assert (u.max() - u.min()) / width == pytest.approx(fill, rel=1e-6)


def test_look_at_gl_is_a_rotation_looking_at_the_origin_also_from_the_pole():
    eyes = np.array([[3.0, -2.0, 1.0], [0.0, 0.0, 4.0], [0.0, 0.0, -4.0], [1.0, 1.0, -2.0]])
    c2w = rigs.look_at_gl(eyes)
    for m, e in zip(c2w, eyes, strict=True):
        r = m[:3, :3]
        assert np.allclose(r.T @ r, np.eye(3), atol=1e-12) and np.linalg.det(r) > 0
        assert np.allclose(-r[:, 2], -e / np.linalg.norm(e))  # looks down -Z at the origin


def test_pixel_directions_project_back_to_their_pixels():
    c2w = rigs.look_at_gl(np.array([[3.0, -2.0, 1.0]]))[0]
    f, w, h = 50.0, 9, 7
    d = rigs.pixel_directions(c2w, f, w, h)
    assert np.allclose(d[3, 4], -c2w[:3, 2])  # the centre pixel looks down -Z
    pc = d @ c2w[:3, :3]  # camera frame (OpenGL)
    u, v = w / 2 + f * pc[..., 0] / -pc[..., 2], h / 2 - f * pc[..., 1] / -pc[..., 2]
    j, i = np.mgrid[0:h, 0:w]
    assert np.allclose(u, i + 0.5) and np.allclose(v, j + 0.5)


def test_rigs_have_the_requested_views_below_and_above():
    for rig in rigs.RIGS:
        d = rigs.train_directions(rig, 96)
        assert d.shape == (96, 3) and np.allclose(np.linalg.norm(d, axis=1), 1)
    assert rigs.train_directions("rings").max(axis=0)[2] == pytest.approx(1.0)  # straight above
    assert rigs.train_directions("full")[:, 2].min() < math.sin(math.radians(-60))
    train = rigs.train_directions("band")
    test, angle = rigs.test_directions("band", train, 16, seed=3)
    assert test.shape == (16, 3)
    assert math.degrees(math.acos((test @ train.T).max())) == pytest.approx(angle)


# --------------------------------------------------------------------------- env maps

def test_lookup_at_pixel_centres_returns_the_pixels():
    env = np.random.default_rng(0).uniform(size=(envmaps.HEIGHT, envmaps.WIDTH, 3))
    got = envmaps.lookup(env, envmaps.directions())
    # rows 0 and H - 1 are the poles themselves: every column there is the same direction
    assert np.allclose(got[1:-1], env[1:-1], atol=1e-9)


def test_direction_mapping_matches_the_readme_landmarks():
    d = envmaps.directions()
    h, w = envmaps.HEIGHT, envmaps.WIDTH
    assert np.allclose(d[0, 0], [0, 0, 1], atol=1e-12)          # row 0 is the zenith
    assert np.allclose(d[h - 1, 0], [0, 0, -1], atol=1e-12)     # last row the nadir
    mid = h // 2
    # column centre u = 0.25 looks toward +X, 0.5 toward -Y, 0.75 toward -X
    for u, axis in ((0.25, [1, 0, 0]), (0.5, [0, -1, 0]), (0.75, [-1, 0, 0])):
        col = int(round(u * w - 0.5))
        assert np.dot(d[mid, col], axis) > 0.99


def test_sun_sky_has_a_small_sun_ten_thousand_times_the_median():
    env = envmaps.sun_sky(1, 40.0, 30.0)
    assert env.max() / np.median(env) >= 1e4
    # the sun covers about its solid angle; brightness x solid angle does not depend on the grid
    bright = env.max(axis=-1) > 100 * np.median(env)
    theta = math.pi * np.arange(envmaps.HEIGHT) / (envmaps.HEIGHT - 1)
    pix_sr = (2 * math.pi / envmaps.WIDTH) * (math.pi / (envmaps.HEIGHT - 1)) * np.sin(theta)
    area = (bright * pix_sr[:, None]).sum()
    sun_sr = 2 * math.pi * (1 - math.cos(math.radians(0.8)))
    assert 0.5 * sun_sr < area < 4 * sun_sr


def test_room_is_indoor_lit_by_panels_and_a_window():
    env = envmaps.room(3)
    lum = env.mean(axis=-1)
    assert lum.max() == pytest.approx(np.mean([6.0, 5.7, 5.1]), rel=1e-4)
    assert np.median(lum) < 1.0 and (lum > 2).mean() < 0.1


# --------------------------------------------------------------------------- ground-truth maps

def test_material_maps_follow_the_split_height():
    spec = SceneSpec("t", lambda: None, "", (Material("a", (0.1, 0.2, 0.3), 0.0, 0.7),
                                           Material("b", (0.9, 0.8, 0.7), 1.0, 0.2)),
                     "room_a", ("sky_low", "warehouse"), split_z=0.0)
    pos = np.zeros((2, 2, 3))
    pos[0, :, 2], pos[1, :, 2] = -0.5, 0.5
    cov = np.array([[1.0, 0.0], [1.0, 0.5]])
    m = build.material_maps(spec, pos, cov)
    assert np.allclose(m["albedo"][0, 0], [0.1, 0.2, 0.3]) and np.allclose(m["albedo"][0, 1], 0)
    assert m["metallic"][1, 0] == 1.0 and m["roughness"][1, 1] == pytest.approx(0.2)
    assert m["roughness"][0, 1] == 0.0


def test_z_depth_is_along_the_viewing_axis():
    c2w = rigs.look_at_gl(np.array([[0.0, -4.0, 0.0]]))[0]
    pos = np.array([[[0.3, 0.0, 0.2], [0.0, 1.0, 0.0]]])
    d = build.z_depth(pos, np.array([[1.0, 0.0]]), c2w)
    assert d[0, 0] == pytest.approx(4.0) and d[0, 1] == 0.0


# --------------------------------------------------------------------------- report

def _row(scene, preset, px, normal, relight, genus, genus_true, shape_s=100.0):
    return {"scene": scene, "preset": preset, "stage": "both", "status": "ok",
            "time_s": shape_s + 10, "shape_s": shape_s, "material_s": 10.0,
            "chamfer": px * 0.01, "chamfer_px": px, "chamfer_exact_px": 2 * px,
            "normal_deg": normal, "genus": genus,
            "genus_true": genus_true, "components": 1, "psnr_object": 25.0,
            "relight_psnr": relight, "pixel_size": 0.01}


def test_summary_gives_medians_the_worst_scene_and_genus_hits():
    rows = [_row("a", "preview", 1.0, 3.0, 25.0, 1, 1), _row("b", "preview", 3.0, 9.0, 20.0,
                                                             0, 3),
            _row("c", "preview", 2.0, 5.0, 27.0, 0, 0, shape_s=300.0)]
    (s,) = bench.summary(rows)
    assert s["chamfer_px_median"] == 2.0 and s["chamfer_px_worst"] == 3.0
    assert s["worst_scene"] == "b" and s["genus_right"] == "1 / 2"
    assert s["relight_psnr_worst"] == 20.0 and s["shape_s_worst"] == 300.0
    assert s["chamfer_exact_px_median"] == 4.0 and s["chamfer_exact_px_worst"] == 6.0
    md = bench.markdown(rows)
    assert "| b | `preview` | 3.00 | 0.0300 | 6.00 |" in md and "0 (3)" in md


def test_mesh_topology_reads_the_largest_component(tmp_path):
    from voxnero.synth.writer import write_mesh

    big = shapes.mesh_sdf(shapes.torus(0.5, 0.2), 48)
    small = shapes.mesh_sdf(shapes.transformed(shapes.sphere(0.05), offset=(0.0, 0.0, 0.7)), 48)
    v = np.concatenate([big.vertices, small.vertices])
    t = np.concatenate([big.triangles, small.triangles + len(big.vertices)])
    n = np.concatenate([big.normals, small.normals])
    write_mesh(tmp_path / "m.ply", v, t, n)
    assert mesh_topology(tmp_path / "m.ply") == (1, 2)


def test_collect_finds_the_mesh_of_a_point_with_overrides(tmp_path):
    """A point with overrides names its own run folder: the corpus table reads that run's mesh
    (its genus), not the bare preset's folder."""
    import csv

    from voxnero.synth.writer import write_mesh

    corpus, out = tmp_path / "corpus", tmp_path / "out"
    (corpus / "ring").mkdir(parents=True)
    (corpus / "ring" / "scene_info.json").write_text('{"pixel_size": 0.01, "genus": 1}')
    point = "preview shape.coarse.race=false"
    header = ("scene,scene_path,point,preset,overrides,stage,repeat,status,time_s,shape_s,"
              "material_s,shape_train_s,material_train_s,peak_rss_mib,chamfer,normal_deg,psnr,"
              "jobs,load1,started,host").split(",")
    row = dict.fromkeys(header, "")
    row.update(scene="ring", scene_path=str(corpus / "ring"), point=point, preset="preview",
               overrides="shape.coarse.race=false", stage="shape", repeat="0", status="ok",
               time_s="10", shape_s="10", chamfer="0.005", normal_deg="3.0")
    out.mkdir()
    with open(out / "tradeoff.csv", "w", newline="") as f:
        w = csv.DictWriter(f, header)
        w.writeheader()
        w.writerow(row)
    torus = shapes.mesh_sdf(shapes.torus(0.5, 0.2), 48)
    sdir = bench.run_dirs(out, "ring", point)[0]
    sdir.mkdir(parents=True)
    write_mesh(sdir / "mesh.ply", torus.vertices, torus.triangles, torus.normals)
    (sdir / "eval").mkdir()
    (sdir / "eval" / "metrics.json").write_text('{"chamfer_exact": {"cd": 0.008}}')
    (r,) = bench.collect(corpus, out)
    assert r["genus"] == 1 and r["components"] == 1
    assert r["chamfer_px"] == pytest.approx(0.5)
    assert r["chamfer_exact_px"] == pytest.approx(0.8)  # a stage-1 point: its own eval


@pytest.mark.slow
def test_mitsuba_background_matches_the_env_map_convention():
    """The written convention (camera axes, env-map orientation) agrees with Mitsuba's."""
    pytest.importorskip("mitsuba")
    from tools.corpus import render

    render.set_variant()
    env = envmaps.room(3)
    m = shapes.mesh_sdf(shapes.sphere(0.5), 48)
    r = render.Renderer([render.Part(m.vertices, m.triangles, m.normals, (0.5, 0.5, 0.5), 0.0,
                                     0.5)], env, 64, 64, rigs.FOV_X_DEG)
    c2w = rigs.look_at_gl(np.array([[3.0, -2.0, 1.0]]))[0]
    f = 0.5 * 64 / math.tan(math.radians(rigs.FOV_X_DEG) / 2)
    rgb = r.radiance(c2w, 64, 0)
    cov = r.geometry(c2w, 16, 0)["coverage"]
    assert build.background_check(env, rgb, cov, c2w, f) > 30.0


def test_background_consistency_finds_what_the_env_map_does_not_explain():
    """Six views along the same directions see one smooth environment; an 'object' patch sits
    in two of them at different places: it is found there and nowhere else."""
    c2w = rigs.look_at_gl(np.array([[3.0, -2.0, 1.0]]))[0]
    d = rigs.pixel_directions(c2w, 40.0, 48, 32)
    env = 0.5 + 0.3 * np.stack([d[..., 0], d[..., 1], d[..., 2]], -1)  # smooth in direction
    images = np.repeat(env[None], 6, axis=0)
    truth = np.zeros((6, 32, 48), bool)
    truth[1, 5:12, 10:20] = truth[4, 18:28, 25:40] = True
    images[truth] = [0.9, 0.1, 0.1]
    pred = bg_consistency.object_mask(images, np.repeat(d[None], 6, axis=0), bins_w=128)
    assert np.array_equal(pred, truth)


@pytest.mark.slow
def test_mitsuba_per_vertex_material_matches_the_uniform_one_and_follows_the_vertices():
    """The relight check renders an exported asset with per-vertex parameters: constant values
    per vertex render like the uniform part (same seed), and a base colour that differs between
    the two halves of a sphere shows up on those halves."""
    pytest.importorskip("mitsuba")
    from tools.corpus import render

    render.set_variant()
    env = envmaps.room(3)
    m = shapes.mesh_sdf(shapes.sphere(0.5), 48)
    V = len(m.vertices)
    c2w = rigs.look_at_gl(np.array([[3.0, 0.0, 0.0]]))[0]  # looks along -x: +y is image right

    def img(base, met, rough):
        part = render.Part(m.vertices, m.triangles, m.normals, base, met, rough)
        return render.Renderer([part], env, 48, 48, rigs.FOV_X_DEG).radiance(c2w, 32, 0)

    uni = img((0.6, 0.3, 0.2), 0.0, 0.5)
    per = img(np.tile([0.6, 0.3, 0.2], (V, 1)), np.zeros(V), np.full(V, 0.5))
    assert np.abs(per - uni).max() < 1e-4
    split = np.where(m.vertices[:, 1:2] > 0, [0.9, 0.9, 0.9], [0.05, 0.05, 0.05])
    two = img(split, np.zeros(V), np.full(V, 0.5))
    left, right = two[18:30, 14:20].mean(), two[18:30, 28:34].mean()  # y > 0 is image right
    assert right > 3 * left, (left, right)
