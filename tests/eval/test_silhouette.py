"""Capture evaluation without a GT mesh (voxnero/eval/silhouette.py, voxnero/eval/capture.py):
culling by training masks and silhouette scores against closed forms on a code-built NeuS/IDR
capture of a sphere."""

from __future__ import annotations

import json

import numpy as np
import open3d as o3d
import pytest

from tests.fixtures.scenes import SPHERE_C, SPHERE_R, make_idr
from voxnero.cli import main
from voxnero.data.idr import load_idr
from voxnero.eval.silhouette import (
    cull_by_masks,
    cull_mesh,
    cull_refined,
    disk_dilate,
    silhouette_scores,
    silhouettes,
    split_triangles,
)


def sphere_mesh(center, radius, res: int = 200) -> o3d.geometry.TriangleMesh:
    m = o3d.geometry.TriangleMesh.create_sphere(radius=1.0, resolution=res)
    v = np.asarray(m.vertices)
    # vertices on the sphere, faces inside: push out to the circumscribed radius of a facet
    m.vertices = o3d.utility.Vector3dVector(v * radius * 1.0005 + np.asarray(center))
    return m


def table_mesh(center, size: float) -> o3d.geometry.TriangleMesh:
    """A flat box under the sphere (what a capture's region of interest also holds)."""
    b = o3d.geometry.TriangleMesh.create_box(size, size, 0.05)
    b.translate(np.asarray(center) - (size / 2, size / 2, 0))
    return b


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    root = tmp_path_factory.mktemp("idr")
    make_idr(root, n=17, zoom=4)
    return root, load_idr(root, splits=("train", "test"), eval_extras=True)


def unit(sc, mesh):
    out = o3d.geometry.TriangleMesh(mesh)
    out.vertices = o3d.utility.Vector3dVector(sc.norm.to_unit(np.asarray(mesh.vertices)))
    return out


def test_true_mesh_scores_one(capture):
    _, sc = capture
    te = sc.split("test")
    s = silhouette_scores(silhouettes(unit(sc, sphere_mesh(SPHERE_C, SPHERE_R)), te.cameras),
                          te.masks)
    assert s["iou"] > 0.985 and s["precision"] > 0.985 and s["recall"] > 0.985
    assert len(s["per_view"]["iou"]) == te.n == 3


def test_shrunken_mesh_gives_closed_form_iou(capture):
    """Cameras look at the sphere's centre from distance 4: the silhouette of a sphere of radius
    r is an ellipse of semi-axes f tan(asin(r / 4)), so a concentric smaller sphere scores
    IoU = precision... = (t_small / t_true)^2 with t = r / sqrt(16 - r^2)."""
    _, sc = capture
    te = sc.split("test")
    r = 0.7 * SPHERE_R
    s = silhouette_scores(silhouettes(unit(sc, sphere_mesh(SPHERE_C, r)), te.cameras), te.masks)
    t = lambda x: x / np.sqrt(16 - x * x)  # noqa: E731
    expect = (t(r) / t(SPHERE_R)) ** 2
    assert s["iou"] == pytest.approx(expect, abs=0.02)
    assert s["precision"] > 0.99 and s["recall"] == pytest.approx(expect, abs=0.02)


def test_culling_removes_the_table_and_keeps_the_object(capture):
    _, sc = capture
    tr, te = sc.split("train"), sc.split("test")
    obj = sphere_mesh(SPHERE_C, SPHERE_R, res=60)
    scene_mesh = unit(sc, obj + table_mesh(SPHERE_C - (0, 0, SPHERE_R + 0.02), 3.0))
    keep, rec = cull_by_masks(np.asarray(scene_mesh.vertices), tr.cameras, tr.masks)
    n_obj = len(obj.vertices)
    assert keep[:n_obj].all()  # every object vertex projects into every (dilated) mask
    assert keep[n_obj:].mean() < 0.05  # the table is gone (its corners are outside all masks)
    before = silhouette_scores(silhouettes(scene_mesh, te.cameras), te.masks)
    after = silhouette_scores(silhouettes(cull_mesh(scene_mesh, keep), te.cameras), te.masks)
    assert before["precision"] < 0.6 and after["iou"] > 0.97
    assert rec["views"] == tr.n and rec["dilate_px"] == 2


def test_points_unseen_by_a_view_are_judged_by_the_others(capture):
    from voxnero.cameras.rays import image_rays

    _, sc = capture
    tr = sc.split("train")
    cams, masks = tr.cameras[:1], tr.masks[:1]
    c = sc.norm.to_unit(SPHERE_C)
    o, d = image_rays(cams, 0)
    corner = (o[2, 2] + 1.0 * d[2, 2]).numpy()  # seen by the view, outside its mask
    behind = (o[0, 0] - 1.0 * cams.c2w[0, :3, 2]).numpy()  # behind the camera: not seen
    keep, rec = cull_by_masks(np.stack([c, corner, behind]), cams, masks)
    assert keep.tolist() == [True, False, True] and rec["unseen"] == 1


def test_disk_dilation_radius():
    m = np.zeros((1, 11, 11), bool)
    m[0, 5, 5] = True
    d = disk_dilate(m, 2)[0]
    assert d.sum() == 13  # lattice points with i^2 + j^2 <= 4
    assert d[5, 7] and d[3, 5] and not d[7, 7]


def test_eval_command_on_a_capture(capture, tmp_path, capsys):
    root, sc = capture
    mesh = sphere_mesh(SPHERE_C, SPHERE_R, res=80) + table_mesh(
        SPHERE_C - (0, 0, SPHERE_R + 0.02), 3.0)
    path = tmp_path / "m.ply"
    o3d.io.write_triangle_mesh(str(path), mesh)  # input (world) frame, as stage 1 writes it
    assert main(["eval", str(path), "--scene", str(root), "--out", str(tmp_path / "e")]) == 0
    out = capsys.readouterr().out
    assert "silhouette IoU" in out
    m = json.loads((tmp_path / "e" / "metrics.json").read_text())
    assert m["silhouette"]["iou"] > 0.97 and m["n_views"] == 3 and m["n_train_views"] == 14
    assert (tmp_path / "e" / "mesh_culled.ply").is_file()


def _down_camera(size: int = 64):
    """One OpenCV camera at (0, 0, 2) looking down -z; the image spans x, y in [-1, 1] at z = 0."""
    import torch

    from voxnero.cameras.cameras import Cameras

    f = float(size)
    K = torch.tensor([[[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]]])
    c2w = torch.eye(4)[None].clone()
    c2w[0, :3, 1] = torch.tensor([0.0, -1.0, 0.0])  # image down = world -y
    c2w[0, :3, 2] = torch.tensor([0.0, 0.0, -1.0])  # forward = world -z
    c2w[0, :3, 3] = torch.tensor([0.0, 0.0, 2.0])
    return Cameras(K, c2w, size, size)


def test_split_triangles_keeps_the_surface():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    t = np.array([[0, 1, 2], [1, 3, 2]])
    v2, t2 = split_triangles(v, t, np.array([True, False]))
    assert len(t2) == 5 and len(v2) == 7  # 1 kept + 4 new; three midpoints
    area = lambda vv, tt: 0.5 * np.linalg.norm(  # noqa: E731
        np.cross(vv[tt[:, 1]] - vv[tt[:, 0]], vv[tt[:, 2]] - vv[tt[:, 0]]), axis=1)
    assert np.isclose(area(v2, t2).sum(), 1.0)  # same surface
    n = np.cross(v2[t2[:, 1]] - v2[t2[:, 0]], v2[t2[:, 2]] - v2[t2[:, 0]])
    assert (n[:, 2] > 0).all()  # winding kept (all counter-clockwise from +z)


def test_culling_a_coarse_mesh_removes_pixels_not_triangles():
    """Two triangles fill a view whose mask is its left half: per vertex, every triangle has a
    vertex on the right and all is culled; split along the boundary, the left half stays."""
    cams = _down_camera(64)
    mask = np.zeros((1, 64, 64), bool)
    mask[:, :, :32] = True  # x < 0
    corners = 0.9 * np.array([[-1, -1, 0], [1, -1, 0], [-1, 1, 0], [1, 1, 0.0]])
    quad = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(corners),
        o3d.utility.Vector3iVector(np.array([[0, 1, 2], [1, 3, 2]], np.int32)))
    keep, _ = cull_by_masks(np.asarray(quad.vertices), cams, mask, dilate_px=0)
    assert len(cull_mesh(quad, keep).triangles) == 0
    culled, rec = cull_refined(quad, cams, mask, dilate_px=0, edge_px=1.0, rounds=8)
    assert rec["refine"]["rounds"] >= 5
    truth = silhouettes(quad, cams) & mask  # the quad's pixels inside the mask
    s = silhouette_scores(silhouettes(culled, cams), truth)
    assert s["precision"] == 1.0 and s["recall"] > 0.95  # within ~a pixel of the boundary
    off, _ = cull_refined(quad, cams, mask, dilate_px=0, edge_px=0.0)
    assert len(off.triangles) == 0  # edge_px = 0: per vertex, as before
