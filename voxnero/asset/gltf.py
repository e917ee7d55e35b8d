"""glTF 2.0 binary (``.glb``): the writer of stage 2's textured PBR mesh (a small writer of our
own) and its reader, back into the scene's input frame.

Open3D's glTF writer keeps only a base-colour texture and writes a metallic *factor* that
multiplies the texture, so the asset is written here directly: one mesh, one primitive
(POSITION, NORMAL, TEXCOORD_0, uint32 indices), one ``pbrMetallicRoughness`` material with

* ``baseColorTexture``: 8-bit PNG, **sRGB-encoded** linear albedo (as the spec requires),
* ``metallicRoughnessTexture``: 8-bit PNG, **linear**, G = roughness (perceptual r, the
  renderer squares it), B = metallic, R unused (0),

and every factor 1 so the textures are the values. glTF is +Y up: positions and normals are
written with Blender's exporter axis change ``(x, y, z)_glTF = (x, z, −y)_scene`` (a proper
rotation, -90° about X), recorded in a sidecar ``<name>.json``.

File layout (glTF 2.0 spec, "GLB File Format Specification"): 12-byte header
(magic ``glTF``, version 2, total length), a JSON chunk padded with spaces to 4 bytes, a BIN chunk
padded with zeros to 4 bytes; every buffer view starts at a multiple of 4 bytes.

Reading (:func:`load_glb`) undoes the rotation recorded in the sidecar (``scene_to_gltf``)
exactly (``p_scene = Rᵀ p_glTF``); base colour is decoded from sRGB to linear, the
metallic-roughness texture is linear (G = perceptual roughness, B = metallic); factors multiply
the textures. Any single-primitive glTF 2.0 binary with embedded PNG textures loads.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image

from voxnero.asset.model import Asset, make_asset, material_from_maps
from voxnero.errors import DataError
from voxnero.io.color import linear_to_srgb
from voxnero.render.brdf import check_diffuse

if TYPE_CHECKING:  # the writers take a baked mesh; baking (Open3D) is not needed to read
    from voxnero.asset.textures import TexturedMesh

SCENE_TO_GLTF = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Rotation applied to scene-frame vectors: (x, y, z)_glTF = (x, z, −y)_scene (Blender's)."""

_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_FLOAT, _UINT = 5126, 5125
_COMPONENTS = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def png_bytes(img: np.ndarray) -> bytes:
    """Encode (H, W, 3) values in [0, 1] as an 8-bit RGB PNG (rounded)."""
    q = np.rint(np.clip(np.nan_to_num(img), 0.0, 1.0) * 255).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(q, "RGB").save(buf, format="PNG")
    return buf.getvalue()


def texture_images(tm: TexturedMesh) -> tuple[np.ndarray, np.ndarray]:
    """The two texture images as stored: base colour (sRGB-encoded) and metallic-roughness.

    Returns:
        base (S, S, 3) sRGB in [0, 1]; mr (S, S, 3) linear with R = 0, G = roughness,
        B = metallic.
    """
    base = np.asarray(linear_to_srgb(np.clip(tm.albedo, 0, 1).astype(np.float32)))
    mr = np.zeros(tm.albedo.shape, np.float32)
    mr[..., 1] = tm.roughness
    mr[..., 2] = tm.metallic
    return base, mr


DIFFUSE_NOTES = {
    "principled": "base colour fitted with the diffuse lobe of the principled BSDF (Disney / "
                  "Burley 2015, with retro-reflection, not weighted by the specular Fresnel: "
                  "Mitsuba's and Cycles' principled). A renderer using glTF's fresnel_mix "
                  "(Lambert weighted by 1 - F) shows dielectrics a few percent darker.",
    "weighted": "base colour fitted with glTF's fresnel_mix diffuse (Lambert weighted by the "
                "specular interface's 1 - F).",
}


def diffuse_sidecar(diffuse: str) -> dict[str, str]:
    """Sidecar entries naming the diffuse convention the base colour was fitted with
    (``voxnero.render.brdf.DIFFUSE_MODELS``); :func:`load_glb` reads ``diffuse`` back."""
    return {"diffuse": check_diffuse(diffuse), "diffuse_note": DIFFUSE_NOTES[diffuse]}


def write_glb(path: str | Path, tm: TexturedMesh, name: str = "voxnero",
              sidecar: dict | None = None) -> Path:
    """Write ``tm`` (scene frame) as a binary glTF 2.0 file plus ``<path>.json`` sidecar.

    Args:
        path: output ``.glb`` file.
        tm: textured mesh in the scene's input frame.
        name: mesh / material name.
        sidecar: extra entries for the sidecar JSON (e.g. the scene's up axis).

    Returns:
        The path written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    R = SCENE_TO_GLTF.astype(np.float32)
    pos = np.ascontiguousarray(tm.positions.astype(np.float32) @ R.T)
    nrm = np.ascontiguousarray(tm.normals.astype(np.float32) @ R.T)
    uv = np.ascontiguousarray(tm.uvs.astype(np.float32))
    idx = np.ascontiguousarray(tm.indices.astype(np.uint32).reshape(-1))
    base, mr = texture_images(tm)
    blobs = [pos.tobytes(), nrm.tobytes(), uv.tobytes(), idx.tobytes(), png_bytes(base),
             png_bytes(mr)]
    targets = [_ARRAY_BUFFER] * 3 + [_ELEMENT_ARRAY_BUFFER, None, None]
    bin_ = bytearray()
    views = []
    for blob, target in zip(blobs, targets, strict=True):
        while len(bin_) % 4:
            bin_.append(0)
        view = {"buffer": 0, "byteOffset": len(bin_), "byteLength": len(blob)}
        if target is not None:
            view["target"] = target
        views.append(view)
        bin_ += blob
    while len(bin_) % 4:
        bin_.append(0)
    nv = int(pos.shape[0])
    accessors = [
        {"bufferView": 0, "componentType": _FLOAT, "count": nv, "type": "VEC3",
         "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
        {"bufferView": 1, "componentType": _FLOAT, "count": nv, "type": "VEC3"},
        {"bufferView": 2, "componentType": _FLOAT, "count": nv, "type": "VEC2"},
        {"bufferView": 3, "componentType": _UINT, "count": int(idx.shape[0]), "type": "SCALAR"},
    ]
    doc = {
        "asset": {"version": "2.0", "generator": "VoxNeRO stage 2"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "meshes": [{"name": name, "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2},
            "indices": 3, "material": 0, "mode": 4}]}],
        "materials": [{"name": name, "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
            "baseColorTexture": {"index": 0, "texCoord": 0},
            "metallicFactor": 1.0, "roughnessFactor": 1.0,
            "metallicRoughnessTexture": {"index": 1, "texCoord": 0}}}],
        "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}],
        "images": [{"bufferView": 4, "mimeType": "image/png", "name": "baseColor"},
                   {"bufferView": 5, "mimeType": "image/png", "name": "metallicRoughness"}],
        "textures": [{"sampler": 0, "source": 0}, {"sampler": 0, "source": 1}],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(bin_)}],
    }
    js = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    js += b" " * ((4 - len(js) % 4) % 4)
    total = 12 + 8 + len(js) + 8 + len(bin_)
    with open(path, "wb") as f:
        f.write(struct.pack("<4sII", b"glTF", 2, total))
        f.write(struct.pack("<I4s", len(js), b"JSON"))
        f.write(js)
        f.write(struct.pack("<I4s", len(bin_), b"BIN\x00"))
        f.write(bytes(bin_))
    meta = {"file": path.name, "frame": "input frame of the scene, axes changed for glTF (+Y up)",
            "scene_to_gltf": SCENE_TO_GLTF.tolist(),
            "rule": "(x, y, z)_glTF = (x, z, -y)_scene (Blender's glTF exporter)",
            "textures": {"baseColor": "sRGB-encoded linear albedo, 8-bit",
                         "metallicRoughness": "linear 8-bit: G = perceptual roughness r "
                                              "(GGX alpha = r^2), B = metallic, R unused"},
            "factors": "all 1 (textures are the values)"}
    meta.update(sidecar or {})
    path.with_suffix(path.suffix + ".json").write_text(json.dumps(meta, indent=1))
    return path


def read_glb(path: str | Path) -> tuple[dict, bytes]:
    """Split a ``.glb`` file into its JSON document and BIN chunk (checks the header).

    Raises:
        ValueError: not a glTF 2.0 binary or inconsistent lengths.
    """
    data = Path(path).read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF" or version != 2 or length != len(data):
        raise ValueError(f"{path}: not a glTF 2.0 binary (magic {magic!r}, version {version}, "
                         f"length {length} vs {len(data)})")
    jlen, jtype = struct.unpack_from("<I4s", data, 12)
    if jtype != b"JSON" or jlen % 4:
        raise ValueError(f"{path}: first chunk must be JSON with a length multiple of 4")
    doc = json.loads(data[20:20 + jlen])
    off = 20 + jlen
    binary = b""
    if off < len(data):
        blen, btype = struct.unpack_from("<I4s", data, off)
        if btype != b"BIN\x00" or blen % 4 or off + 8 + blen != len(data):
            raise ValueError(f"{path}: bad BIN chunk")
        binary = data[off + 8:off + 8 + blen]
    return doc, binary


def _decode_png(blob: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(blob)) as im:
        return np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0


def _accessor(doc: dict, binary: bytes, k: int) -> np.ndarray:
    acc = doc["accessors"][k]
    view = doc["bufferViews"][acc["bufferView"]]
    dt = np.dtype(_COMPONENTS[acc["componentType"]])
    nc = _NCOMP[acc["type"]]
    off = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride", 0) or dt.itemsize * nc
    n = acc["count"]
    if stride == dt.itemsize * nc:
        a = np.frombuffer(binary, dt, n * nc, off).reshape(n, nc)
    else:
        a = np.stack([np.frombuffer(binary, dt, nc, off + i * stride) for i in range(n)])
    return a.astype(np.float64 if dt == np.float32 else np.int64)


def load_glb(path: str | Path) -> Asset:
    """Load ``model.glb`` written by :func:`write_glb` (or any single-primitive glTF 2.0
    binary with a metallic-roughness material) back into the scene's input frame.

    Args:
        path: the ``.glb`` file; ``<path>.json`` (sidecar) gives ``scene_to_gltf`` and
            ``scene_up``; without it the glTF frame is kept (+Y up).

    Returns:
        The :class:`Asset`.

    Raises:
        DataError: unreadable file or missing parts.
    """
    path = Path(path)
    try:
        doc, binary = read_glb(path)
    except (OSError, ValueError, struct.error) as e:
        raise DataError(f"cannot read glTF binary ({e})", path=path,
                        fix="pass a model.glb written by 'voxnero material'") from None
    try:
        prim = doc["meshes"][0]["primitives"][0]
        att = prim["attributes"]
        pos = _accessor(doc, binary, att["POSITION"])
        idx = _accessor(doc, binary, prim["indices"]).reshape(-1, 3)
        nrm = _accessor(doc, binary, att["NORMAL"]) if "NORMAL" in att else None
        uv = _accessor(doc, binary, att["TEXCOORD_0"]) if "TEXCOORD_0" in att else None
        pbr = doc["materials"][prim["material"]].get("pbrMetallicRoughness", {}) \
            if "material" in prim else {}
    except (KeyError, IndexError) as e:
        raise DataError(f"glTF file lacks a mesh primitive part ({e})", path=path,
                        fix="export one mesh with POSITION, indices and a PBR material") from None

    def image(tex_ref: dict | None) -> np.ndarray | None:
        if tex_ref is None:
            return None
        img = doc["images"][doc["textures"][tex_ref["index"]]["source"]]
        if "bufferView" not in img:
            raise DataError("texture image is an external file (uri), not embedded", path=path,
                            fix="embed the textures (a .glb as 'voxnero material' writes it)")
        view = doc["bufferViews"][img["bufferView"]]
        off = view.get("byteOffset", 0)
        return _decode_png(binary[off:off + view["byteLength"]])

    side = path.with_suffix(path.suffix + ".json")
    meta = json.loads(side.read_text()) if side.is_file() else {}
    R = np.asarray(meta.get("scene_to_gltf", np.eye(3)), dtype=np.float64)
    # rows are row vectors in the file: p_glTF = R p_scene  =>  p_scene = R^T p_glTF
    pos = pos @ R
    if nrm is None:
        nrm = np.zeros_like(pos)
    nrm = nrm @ R
    up = np.asarray(meta.get("scene_up", R.T @ np.array([0.0, 1.0, 0.0])), dtype=np.float64)

    bcf = np.asarray(pbr.get("baseColorFactor", [1, 1, 1, 1]), dtype=np.float32)[:3]
    mf = float(pbr.get("metallicFactor", 1.0))
    rf = float(pbr.get("roughnessFactor", 1.0))
    base = image(pbr.get("baseColorTexture"))
    mr = image(pbr.get("metallicRoughnessTexture"))
    mat = material_from_maps(uv, base, None if mr is None else mr[..., 2],
                             None if mr is None else mr[..., 1], bcf, mf, rf)
    asset = make_asset(pos, idx, nrm, mat, up, str(path))
    asset.diffuse = check_diffuse(str(meta.get("diffuse", "weighted")))
    if meta.get("scene"):
        asset.scene = Path(meta["scene"])
    return asset
