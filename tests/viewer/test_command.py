"""``voxnero view`` takes what the other commands write: a ``reconstruct`` output folder is
shown as its stage-2 asset beside its stage-1 mesh (the rendering itself is stubbed out here;
``test_screenshot.py`` renders for real)."""

from __future__ import annotations

import shutil

import open3d as o3d

from tests.fixtures.assets import textured_sphere
from voxnero.cli import build_parser


def test_view_accepts_a_reconstruct_folder(viewer_glb, tmp_path, monkeypatch):
    run = tmp_path / "recon"
    (run / "material").mkdir(parents=True)
    for f in viewer_glb.parent.iterdir():  # model.glb + sidecar, model.obj + .mtl + textures
        shutil.copy(f, run / "material" / f.name)
    (run / "shape").mkdir()
    mesh, _, _ = textured_sphere()
    o3d.io.write_triangle_mesh(str(run / "shape" / "mesh.ply"), mesh)

    seen = {}

    def fake_render(drawables_per_shot, paths, *args, **kwargs):
        seen["names"] = [[d.name for d in shot] for shot in drawables_per_shot]
        seen["paths"] = paths

    import voxnero.viewer.screenshot as screenshot

    monkeypatch.setattr(screenshot, "render_screenshots", fake_render)
    args = build_parser().parse_args(["view", str(run), "--screenshot",
                                      str(tmp_path / "shot.png"), "--size", "64x48"])
    assert args._run(args) == 0
    assert seen["names"] == [["asset", "stage1_mesh"]]
    assert [str(p) for p in seen["paths"]] == [str(tmp_path / "shot.png")]
