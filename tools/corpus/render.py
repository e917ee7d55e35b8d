"""Mitsuba 3 renders of one corpus scene: radiance, coverage and ground-truth AOVs.

Independent of VoxNeRO's own renderer on purpose (the model must not agree with itself):
Mitsuba's ``path`` integrator (``max_depth`` 16, Russian roulette from depth 8), ``independent``
sampler, ``box`` reconstruction filter, the ``principled`` BSDF wrapped in ``twosided``, and the
``envmap`` emitter rotated so the map's up is world +Z — the settings of ../shared/data.

Conventions at this boundary: camera-to-world matrices in, OpenGL (Blender) axes; Mitsuba's
sensor frame is x left, y up, z forward, i.e. ``c2w_gl @ diag(-1, 1, -1, 1)``. Outputs are
linear radiance ``(H, W, 3)``, coverage ``(H, W)`` in [0, 1] (the film's alpha: the fraction of
the pixel's samples whose camera ray hits the object) and, for AOV renders, the average world
position and shading normal over the covered part of each pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

VARIANTS = ("llvm_ad_rgb", "scalar_rgb")
"""Tried in order: the JIT variant needs Debian's libllvm19; scalar is ~10x slower."""


def set_variant() -> str:
    """Select the fastest Mitsuba variant that loads here; returns its name."""
    import mitsuba as mi

    for v in VARIANTS:
        try:
            mi.set_variant(v)
            return v
        except (ImportError, AttributeError, RuntimeError):
            continue
    raise RuntimeError("no Mitsuba variant loads: install libllvm19 (apt) or check mitsuba")


@dataclass
class Part:
    """One material region of the object: a closed or open piece of the mesh and its
    Mitsuba ``principled`` parameters (``base_color`` linear RGB, ``metallic``, ``roughness``;
    GGX ``alpha = roughness²``; ``specular`` 0.5 = dielectric F0 0.04)."""

    vertices: np.ndarray
    triangles: np.ndarray
    normals: np.ndarray
    base_color: tuple[float, float, float] | np.ndarray
    metallic: float | np.ndarray
    roughness: float | np.ndarray
    """Each either one value for the part or one per vertex (``(V, 3)``, ``(V,)``, ``(V,)``),
    interpolated over the triangles (how an exported asset's material is rendered)."""

    def per_vertex(self) -> dict[str, np.ndarray]:
        """The parameters given per vertex, as Mitsuba mesh attributes ``vertex_<name>``."""
        out = {}
        for key, val, ch in (("base_color", self.base_color, 3), ("metallic", self.metallic, 1),
                             ("roughness", self.roughness, 1)):
            a = np.asarray(val, np.float32)
            if a.ndim > 0 and a.shape[0] == len(self.vertices) and a.size != ch:
                out[key] = a.reshape(len(self.vertices), ch)
        return out


def _mesh(mi, part: Part, name: str):
    """A ``mitsuba.Mesh`` from numpy arrays (vertex normals kept: smooth shading; per-vertex
    material parameters as ``vertex_*`` attributes)."""
    m = mi.Mesh(name, len(part.vertices), len(part.triangles), has_vertex_normals=True)
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(np.ascontiguousarray(part.vertices, np.float32).ravel())
    p["faces"] = mi.UInt32(np.ascontiguousarray(part.triangles, np.uint32).ravel())
    p["vertex_normals"] = mi.Float(np.ascontiguousarray(part.normals, np.float32).ravel())
    p.update()
    for key, a in part.per_vertex().items():
        m.add_attribute(f"vertex_{key}", a.shape[1], mi.Float(np.ascontiguousarray(a).ravel()))
    return m


def _bsdf(part: Part) -> dict:
    varying = part.per_vertex()

    def value(key: str, v):
        if key in varying:
            return {"type": "mesh_attribute", "name": f"vertex_{key}"}
        if key == "base_color":
            return {"type": "rgb", "value": [float(c) for c in v]}
        return float(v)

    return {"type": "twosided", "material": {
        "type": "principled", "base_color": value("base_color", part.base_color),
        "metallic": value("metallic", part.metallic),
        "roughness": value("roughness", part.roughness),
        "specular": 0.5, "spec_tint": 0.0, "anisotropic": 0.0, "sheen": 0.0,
        "clearcoat": 0.0, "spec_trans": 0.0}}


class Renderer:
    """Renders one object under one env map from many cameras, reusing the compiled kernels.

    Two Mitsuba scenes share the object: one for radiance (``path``, the environment visible)
    and one for geometry (``aov`` around a ``path`` with ``hide_emitters``, so that the film's
    alpha is the fraction of samples whose camera ray hits the object — with a visible
    environment Mitsuba's alpha is 1 everywhere).

    Args:
        parts: the object's material regions.
        env: ``(He, We, 3)`` linear radiance map (convention of ``envmaps``).
        width, height: image size (px); ``fov_deg``: horizontal field of view.
    """

    def __init__(self, parts: list[Part], env: np.ndarray, width: int, height: int,
                 fov_deg: float):
        import mitsuba as mi

        self.mi = mi
        self.scene = self._scene(parts, env, width, height, fov_deg,
                                 {"type": "path", "max_depth": 16, "rr_depth": 8})
        self.geo = self._scene(parts, env, width, height, fov_deg,
                               {"type": "aov", "aovs": "pp:position,nn:sh_normal",
                                "inner": {"type": "path", "max_depth": 1,
                                          "hide_emitters": True}})
        self.params = [mi.traverse(self.scene), mi.traverse(self.geo)]

    def _scene(self, parts, env, width, height, fov_deg, integrator):
        mi = self.mi
        scene = {
            "type": "scene", "integrator": integrator,
            "sensor": {"type": "perspective", "fov": fov_deg, "fov_axis": "x",
                       "near_clip": 0.01, "far_clip": 100.0,
                       "to_world": mi.ScalarTransform4f(),
                       "sampler": {"type": "independent", "sample_count": 4},
                       "film": {"type": "hdrfilm", "width": width, "height": height,
                                "rfilter": {"type": "box"}, "pixel_format": "rgba",
                                "sample_border": False}},
            "env": {"type": "envmap",
                    "bitmap": mi.Bitmap(np.ascontiguousarray(env[..., :3], np.float32)),
                    "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90.0)},
        }
        for i, part in enumerate(parts):
            m = _mesh(mi, part, f"part{i}")
            m.set_bsdf(mi.load_dict(_bsdf(part)))
            scene[f"part{i}"] = m
        return mi.load_dict(scene)

    def _look(self, c2w_gl: np.ndarray) -> None:
        m = np.asarray(c2w_gl, dtype=np.float64) @ np.diag([-1.0, 1.0, -1.0, 1.0])
        for p in self.params:
            p["sensor.to_world"] = self.mi.Transform4f(m.tolist())
            p.update()

    def radiance(self, c2w_gl: np.ndarray, spp: int, seed: int) -> np.ndarray:
        """``(H, W, 3)`` linear radiance of one view (box-filtered pixel averages)."""
        self._look(c2w_gl)
        img = np.array(self.mi.render(self.scene, spp=spp, seed=seed), dtype=np.float32)
        return img[..., :3]

    def geometry(self, c2w_gl: np.ndarray, spp: int, seed: int) -> dict[str, np.ndarray]:
        """Coverage ``(H, W)`` in [0, 1], and world ``position`` / shading ``normal``
        ``(H, W, 3)`` averaged over the covered samples of each pixel (0 where none is;
        normals renormalised)."""
        self._look(c2w_gl)
        img = np.array(self.mi.render(self.geo, spp=spp, seed=seed), dtype=np.float64)
        alpha = np.clip(img[..., 3], 0.0, 1.0)
        hit = (alpha > 1e-6)[..., None]
        safe = np.where(hit, alpha[..., None], 1.0)
        pos = np.where(hit, img[..., 4:7] / safe, 0.0)
        nrm = img[..., 7:10]
        nrm = np.where(hit, nrm / np.maximum(np.linalg.norm(nrm, axis=-1, keepdims=True), 1e-12),
                       0.0)
        return {"coverage": alpha.astype(np.float32), "position": pos.astype(np.float32),
                "normal": nrm.astype(np.float32)}
