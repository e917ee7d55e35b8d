"""Interactive viewer window (Open3D ``O3DVisualizer``).

Every channel of the asset is added as its own geometry; the actions panel (and the keys of
the "Scene" panel) switch which one is shown, so a switch costs no reload. Camera frusta, their
photos and the stage-1 mesh are separate geometries that can be toggled in the geometry list.
Needs a display (e.g. ``xvfb-run -a voxnero view ...`` on a server) and a GL/Vulkan driver.
"""

from __future__ import annotations

from voxnero.viewer.geometry import CHANNELS, Drawable


def open_window(channel_drawables: dict[str, Drawable], extras: list[Drawable],
                channel: str = "shaded", title: str = "VoxNeRO viewer",
                width: int = 1280, height: int = 800, close_after_s: float | None = None) -> None:
    """Open the window and run the GUI loop until it is closed.

    Args:
        channel_drawables: one drawable of the asset per channel (:data:`CHANNELS`).
        extras: other drawables (frusta, photos, stage-1 mesh), always listed.
        channel: channel shown first.
        title, width, height: window.
        close_after_s: close the window by itself after this many seconds (tests / smoke runs).
    """
    import threading

    import open3d.visualization.gui as gui
    import open3d.visualization.rendering as rendering  # noqa: F401  (registers materials)
    from open3d.visualization import O3DVisualizer

    app = gui.Application.instance
    app.initialize()
    vis = O3DVisualizer(title, width, height)
    vis.show_settings = True
    for name, d in channel_drawables.items():
        vis.add_geometry(f"asset_{name}", d.geometry, d.material)
        vis.show_geometry(f"asset_{name}", name == channel)
    for d in extras:
        vis.add_geometry(d.name, d.geometry, d.material)

    def switch(to: str):
        def cb(v):
            for name in channel_drawables:
                v.show_geometry(f"asset_{name}", name == to)
        return cb

    for name in CHANNELS:
        if name in channel_drawables:
            vis.add_action(f"show {name}", switch(name))
    vis.reset_camera_to_default()
    app.add_window(vis)
    print(f"[view] window {title!r} open ({width}x{height}); actions switch the channel",
          flush=True)
    if close_after_s is not None:
        def closer():
            import time

            time.sleep(close_after_s)
            app.post_to_main_thread(vis, vis.close)
        threading.Thread(target=closer, daemon=True).start()
    app.run()
