"""``voxnero view``: Open3D viewer of an asset (interactive window or headless screenshots).

``voxnero view ASSET_OR_RUN [--channel shaded|albedo|metallic|roughness|normals]
[--screenshot out.png] [--cameras SCENE]``

ASSET_OR_RUN is a ``voxnero reconstruct`` or ``voxnero material`` output folder, model.glb /
model.obj, or ``gt:SCENE``.
The asset is drawn with a PBR material (``defaultLit`` with its albedo / metallic / roughness
maps) or one channel at a time; ``--cameras SCENE`` adds the scene's training cameras as frusta
with their photos; a run folder's stage-1 mesh (when there is one) stands beside the final mesh.
``--screenshot`` renders headless (Open3D OffscreenRenderer) instead of opening a window; with
several channels (``--channel shaded,albedo`` or ``all``) it writes ``<stem>_<channel>.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "view"
HELP = "Open3D viewer of an asset (window, or headless --screenshot)"
DESCRIPTION = __doc__.split("\n\n", 1)[1]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("target", metavar="ASSET_OR_RUN",
                        help="reconstruct or material run folder, model.glb / model.obj, "
                             "or gt:SCENE")
    parser.add_argument("--channel", default="shaded",
                        help="shaded, albedo, metallic, roughness, normals; a comma list or 'all' "
                             "with --screenshot (default shaded)")
    parser.add_argument("--screenshot", default=None, help="write a PNG headless instead of a "
                                                           "window")
    parser.add_argument("--cameras", default=None, metavar="SCENE",
                        help="scene whose training cameras are drawn (frusta with photos)")
    parser.add_argument("--size", default="640x480", help="screenshot / window size WxH")
    parser.add_argument("--no-stage1", action="store_true", help="do not show the stage-1 mesh")
    parser.add_argument("--close-after", type=float, default=None,
                        help="close the window after this many seconds (smoke tests)")


def _channels(spec: str) -> list[str]:
    from voxnero.errors import ConfigError
    from voxnero.viewer.geometry import CHANNELS

    names = list(CHANNELS) if spec == "all" else [c.strip() for c in spec.split(",") if c.strip()]
    bad = [c for c in names if c not in CHANNELS]
    if bad or not names:
        raise ConfigError(f"unknown channel(s) {bad or spec!r}",
                          fix=f"use one of {', '.join(CHANNELS)}, a comma list or 'all'")
    return names


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from voxnero.asset.load import load_asset
    from voxnero.errors import ConfigError
    from voxnero.viewer.geometry import (
        Drawable,
        asset_mesh,
        camera_drawables,
        channel_material,
        channel_textures,
        side_offset,
        stage1_drawable,
    )

    channels = _channels(args.channel)
    try:
        width, height = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--size {args.size!r} is not WxH", fix="e.g. --size 640x480") from None
    asset = load_asset(args.target)
    mesh = asset_mesh(asset)
    tex = channel_textures(asset)
    per_channel = {c: Drawable("asset", mesh, channel_material(asset, c, tex)) for c in channels}
    extras: list[Drawable] = []
    center, radius = asset.bounds()
    pts = [center + radius * s for s in np.vstack([np.eye(3), -np.eye(3)])]
    if asset.stage1_mesh is not None and not args.no_stage1:
        off = side_offset(asset)
        extras.append(stage1_drawable(asset.stage1_mesh, off))
        pts += [p + off for p in pts]
    if args.cameras:
        from voxnero.relight.cameras import scene_cameras

        cams, _, photos = scene_cameras(args.cameras, "train")
        extras += camera_drawables(cams, photos, size=0.1 * float(
            np.linalg.norm(cams.c2w[:, :3, 3].double().numpy() - center, axis=1).mean()))
        pts += list(cams.c2w[:, :3, 3].double().numpy())
    pts = np.asarray(pts)
    view_c = 0.5 * (pts.min(0) + pts.max(0))
    view_r = float(np.linalg.norm(pts - view_c, axis=1).max())
    if args.screenshot:
        from voxnero.viewer.screenshot import default_view, render_screenshots

        shot = Path(args.screenshot)
        paths = [shot] if len(channels) == 1 else \
            [shot.with_name(f"{shot.stem}_{c}{shot.suffix or '.png'}") for c in channels]
        eye, up = default_view(view_c, view_r, asset.up)
        render_screenshots([[per_channel[c]] + extras for c in channels], paths, view_c, eye,
                           up, width, height)
        print(f"[view] wrote {', '.join(str(p) for p in paths)}")
        return 0
    from voxnero.viewer.geometry import CHANNELS
    from voxnero.viewer.window import open_window

    per_channel = {c: Drawable("asset", mesh, channel_material(asset, c, tex)) for c in CHANNELS}
    open_window(per_channel, extras, channels[0], f"VoxNeRO: {asset.source}", width, height,
                args.close_after)
    return 0
