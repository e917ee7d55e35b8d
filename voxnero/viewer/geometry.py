"""Open3D geometries and materials of the viewer: the asset per channel, the stage-1 mesh and
camera frusta with their photos. Everything is in the scene's input frame.

Channels (:data:`CHANNELS`):

* ``shaded``: ``MaterialRecord`` ``defaultLit`` with the albedo / metallic / roughness maps
  (Filament PBR: base colour sRGB-encoded 8-bit, roughness and metallic linear 8-bit grey);
  a uniform material sets ``base_color`` / ``base_metallic`` / ``base_roughness`` instead;
* ``albedo``, ``metallic``, ``roughness``: ``defaultUnlit`` with the map as the colour
  (albedo sRGB-encoded, the others linear grey, like a texture viewer);
* ``normals``: Open3D's ``normals`` shader (RGB = (n + 1) / 2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CHANNELS = ("shaded", "albedo", "metallic", "roughness", "normals")


@dataclass
class Drawable:
    """One named geometry with its material (what ``scene.add_geometry`` takes)."""

    name: str
    geometry: object
    material: object
    group: str = "asset"


def _image(a: np.ndarray):
    """Open3D image from (H, W[, 3]) values in [0, 1] (8-bit, rounded)."""
    import open3d as o3d

    q = np.ascontiguousarray(np.rint(np.clip(a, 0, 1) * 255).astype(np.uint8))
    if q.ndim == 3 and q.shape[2] == 1:
        q = np.ascontiguousarray(q[..., 0])
    return o3d.geometry.Image(q)


def channel_textures(asset) -> dict[str, np.ndarray] | None:
    """Display textures of a textured asset: ``albedo`` (S, S, 3) sRGB-encoded, ``metallic`` and
    ``roughness`` (S, S, 3) linear grey; None for a uniform material."""
    from voxnero.asset.model import TextureMaterial
    from voxnero.io.color import linear_to_srgb

    m = asset.material
    if not isinstance(m, TextureMaterial):
        return None
    return {"albedo": np.asarray(linear_to_srgb(m.albedo.clamp(0, 1).numpy())),
            "metallic": np.repeat(m.metallic.numpy()[..., None], 3, -1),
            "roughness": np.repeat(m.roughness.numpy()[..., None], 3, -1)}


def asset_mesh(asset):
    """Legacy Open3D mesh of the asset with vertex normals and, if textured, per-corner UVs.

    Open3D's ``triangle_uvs`` have v pointing up (image row = (1 − v)·S, as its UV atlas);
    the asset's UVs are glTF's (v down), so v is flipped here (checked by eye on a baked
    sphere: with unflipped UVs the atlas islands show up scrambled).
    """
    import open3d as o3d

    from voxnero.asset.model import TextureMaterial

    m = asset.legacy_mesh()
    if isinstance(asset.material, TextureMaterial):
        uv = asset.material.uvs.numpy().astype(np.float64)[asset.triangles.numpy().reshape(-1)]
        uv[:, 1] = 1.0 - uv[:, 1]
        m.triangle_uvs = o3d.utility.Vector2dVector(uv)
    return m


def channel_material(asset, channel: str, textures: dict[str, np.ndarray] | None = None):
    """``MaterialRecord`` showing ``channel`` of the asset (see the module docstring).

    Args:
        asset: :class:`voxnero.asset.model.Asset`.
        channel: one of :data:`CHANNELS`.
        textures: :func:`channel_textures` (computed if None).
    """
    import open3d.visualization.rendering as rendering

    from voxnero.asset.model import UniformMaterial
    from voxnero.io.color import linear_to_srgb

    if channel not in CHANNELS:
        from voxnero.errors import ConfigError

        raise ConfigError(f"unknown channel {channel!r}", fix=f"use one of {CHANNELS}")
    mat = rendering.MaterialRecord()
    if channel == "normals":
        mat.shader = "normals"
        return mat
    u = asset.material if isinstance(asset.material, UniformMaterial) else None
    tex = None if u is not None else (textures or channel_textures(asset))
    if channel == "shaded":
        mat.shader = "defaultLit"
        if u is not None:
            mat.base_color = [*np.asarray(linear_to_srgb(np.clip(u.albedo, 0, 1))), 1.0]
            mat.base_metallic, mat.base_roughness = float(u.metallic), float(u.roughness)
        else:
            mat.base_color = [1.0, 1.0, 1.0, 1.0]
            mat.base_metallic = mat.base_roughness = 1.0
            mat.albedo_img = _image(tex["albedo"])
            mat.metallic_img = _image(tex["metallic"][..., :1])
            mat.roughness_img = _image(tex["roughness"][..., :1])
        return mat
    mat.shader = "defaultUnlit"
    if u is not None:
        val = {"albedo": np.asarray(linear_to_srgb(np.clip(u.albedo, 0, 1))),
               "metallic": np.full(3, u.metallic), "roughness": np.full(3, u.roughness)}[channel]
        mat.base_color = [*map(float, val), 1.0]
    else:
        mat.base_color = [1.0, 1.0, 1.0, 1.0]
        mat.albedo_img = _image(tex[channel])
    return mat


def stage1_drawable(path, offset: np.ndarray) -> Drawable:
    """The stage-1 mesh (grey, lit) translated by ``offset`` (3,) to stand beside the asset."""
    import open3d.visualization.rendering as rendering

    from voxnero.mesh.io import load_mesh

    m = load_mesh(path)
    m.translate(np.asarray(offset, dtype=np.float64))
    mat = rendering.MaterialRecord()
    mat.shader = "defaultLit"
    mat.base_color = [0.7, 0.7, 0.7, 1.0]
    mat.base_roughness = 0.6
    return Drawable("stage1_mesh", m, mat, group="stage1")


def camera_drawables(cameras, images: np.ndarray | None, size: float,
                     max_image: int = 64) -> list[Drawable]:
    """Frusta (``LineSet``) of cameras and, if given, their photos on the far plane.

    Args:
        cameras: :class:`voxnero.cameras.cameras.Cameras` in the input frame (OpenCV c2w).
        images: (N, H, W, 3) LINEAR photos or None.
        size: depth of the drawn frustum (input-frame units).
        max_image: photos are subsampled to at most this many pixels across.

    Returns:
        One LineSet drawable for all frusta and one textured quad per photo.
    """
    import open3d as o3d
    import open3d.visualization.rendering as rendering

    from voxnero.io.color import linear_to_srgb

    K = cameras.K.double().numpy()
    c2w = cameras.c2w.double().numpy()
    W, H = cameras.width, cameras.height
    lines = o3d.geometry.LineSet()
    out: list[Drawable] = []
    for i in range(len(cameras)):
        w2c = np.linalg.inv(c2w[i])
        ls = o3d.geometry.LineSet.create_camera_visualization(W, H, K[i], w2c, size)
        lines += ls
        if images is None:
            continue
        # the far-plane corners of the frustum (pixel corners of the image), world frame
        px = np.array([[0, 0], [W, 0], [W, H], [0, H]], dtype=np.float64)
        cam = np.stack([(px[:, 0] - K[i, 0, 2]) / K[i, 0, 0],
                        (px[:, 1] - K[i, 1, 2]) / K[i, 1, 1], np.ones(4)], -1) * size
        world = cam @ c2w[i][:3, :3].T + c2w[i][:3, 3]
        quad = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(world),
                                         o3d.utility.Vector3iVector(np.array([[0, 2, 1],
                                                                              [0, 3, 2]])))
        quad.triangle_uvs = o3d.utility.Vector2dVector(
            np.array([[0, 0], [1, 1], [1, 0], [0, 0], [0, 1], [1, 1]], dtype=np.float64))
        step = max(1, max(images.shape[1:3]) // max_image)
        img = np.asarray(linear_to_srgb(np.clip(images[i][::step, ::step], 0, 1)))
        mat = rendering.MaterialRecord()
        mat.shader = "defaultUnlit"
        mat.albedo_img = _image(img)
        out.append(Drawable(f"photo_{i:03d}", quad, mat, group="cameras"))
    lines.paint_uniform_color([0.9, 0.5, 0.1])
    lm = rendering.MaterialRecord()
    lm.shader = "unlitLine"
    lm.line_width = 1.5
    return [Drawable("frusta", lines, lm, group="cameras")] + out


def side_offset(asset) -> np.ndarray:
    """Where the stage-1 mesh goes: 2.2 bounding radii along a horizontal axis (⟂ up)."""
    _, r = asset.bounds()
    up = np.asarray(asset.up, dtype=np.float64)
    a = np.array([1.0, 0, 0]) if abs(up[0]) < 0.9 else np.array([0, 1.0, 0])
    side = a - up * (a @ up)
    return 2.2 * r * side / np.linalg.norm(side)
