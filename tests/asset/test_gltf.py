"""model.glb: a structural glTF 2.0 validator (the Khronos validator is not installed here) and
a reload by Open3D."""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import open3d as o3d
from PIL import Image

from voxnero.asset.gltf import SCENE_TO_GLTF, read_glb, write_glb
from voxnero.io.color import linear_to_srgb

_COMP = {5126: (np.float32, 4), 5125: (np.uint32, 4), 5123: (np.uint16, 2), 5121: (np.uint8, 1)}
_NCOMP = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def validate_glb(path) -> tuple[dict, dict[int, np.ndarray], list[np.ndarray]]:
    """Check the glTF 2.0 rules this writer relies on; return (doc, accessors, images).

    Header/chunk layout, required top-level properties, index references in range, buffer views
    inside the buffer and 4-byte aligned, accessors inside their views, POSITION min/max equal
    to the data, indices < vertex count, attribute counts equal, images decodable PNGs, texture
    references valid, PBR factors in range.
    """
    doc, binary = read_glb(path)
    assert doc["asset"]["version"] == "2.0"
    assert len(doc["buffers"]) == 1 and doc["buffers"][0]["byteLength"] <= len(binary)
    assert "uri" not in doc["buffers"][0]
    for bv in doc["bufferViews"]:
        assert bv["buffer"] == 0 and bv["byteOffset"] % 4 == 0
        assert bv["byteOffset"] + bv["byteLength"] <= doc["buffers"][0]["byteLength"]
    acc = {}
    for i, a in enumerate(doc["accessors"]):
        bv = doc["bufferViews"][a["bufferView"]]
        dt, size = _COMP[a["componentType"]]
        n = a["count"] * _NCOMP[a["type"]]
        assert a.get("byteOffset", 0) + n * size <= bv["byteLength"]
        data = np.frombuffer(binary, dt, n, bv["byteOffset"] + a.get("byteOffset", 0))
        acc[i] = data.reshape(a["count"], -1)
        assert np.isfinite(acc[i].astype(np.float64)).all()
    assert doc["scene"] < len(doc["scenes"])
    for s in doc["scenes"]:
        assert all(0 <= k < len(doc["nodes"]) for k in s["nodes"])
    for node in doc["nodes"]:
        assert node["mesh"] < len(doc["meshes"])
    for mesh in doc["meshes"]:
        for p in mesh["primitives"]:
            attrs = p["attributes"]
            counts = {doc["accessors"][k]["count"] for k in attrs.values()}
            assert len(counts) == 1
            pos = doc["accessors"][attrs["POSITION"]]
            assert np.allclose(pos["min"], acc[attrs["POSITION"]].min(0))
            assert np.allclose(pos["max"], acc[attrs["POSITION"]].max(0))
            assert doc["accessors"][attrs["NORMAL"]]["type"] == "VEC3"
            nrm = acc[attrs["NORMAL"]]
            assert np.allclose(np.linalg.norm(nrm, axis=1), 1, atol=1e-3)
            idx = acc[p["indices"]]
            assert doc["bufferViews"][doc["accessors"][p["indices"]]["bufferView"]]["target"] \
                == 34963
            assert idx.max() < counts.pop() and idx.size % 3 == 0
            assert p.get("mode", 4) == 4 and p["material"] < len(doc["materials"])
    images = []
    for im in doc["images"]:
        bv = doc["bufferViews"][im["bufferView"]]
        assert im["mimeType"] == "image/png" and "target" not in bv
        raw = binary[bv["byteOffset"]:bv["byteOffset"] + bv["byteLength"]]
        images.append(np.asarray(Image.open(io.BytesIO(raw)).convert("RGB")))
    for t in doc["textures"]:
        assert t["source"] < len(doc["images"]) and t["sampler"] < len(doc["samplers"])
    for m in doc["materials"]:
        pbr = m["pbrMetallicRoughness"]
        assert pbr["baseColorTexture"]["index"] < len(doc["textures"])
        assert pbr["metallicRoughnessTexture"]["index"] < len(doc["textures"])
        assert 0 <= pbr["metallicFactor"] <= 1 and 0 <= pbr["roughnessFactor"] <= 1
    return doc, acc, images


def test_glb_is_valid_and_holds_the_asset(tmp_path, sphere_textured):
    _, tm = sphere_textured
    path = write_glb(tmp_path / "model.glb", tm, sidecar={"scene_up": [0, 0, 1]})
    doc, acc, images = validate_glb(path)
    pbr = doc["materials"][0]["pbrMetallicRoughness"]
    assert pbr["metallicFactor"] == 1 and pbr["roughnessFactor"] == 1
    assert pbr["baseColorFactor"] == [1, 1, 1, 1]
    prim = doc["meshes"][0]["primitives"][0]
    # axis change: (x, y, z)_glTF = (x, z, -y)_scene
    pos = acc[prim["attributes"]["POSITION"]]
    assert np.allclose(pos, np.stack([tm.positions[:, 0], tm.positions[:, 2],
                                      -tm.positions[:, 1]], 1), atol=1e-6)
    assert np.allclose(acc[prim["attributes"]["TEXCOORD_0"]], tm.uvs)
    assert np.array_equal(acc[prim["indices"]].reshape(-1, 3), tm.indices)
    # base colour is sRGB-encoded albedo, metallicRoughness linear with G = r, B = m
    base = images[doc["textures"][pbr["baseColorTexture"]["index"]]["source"]]
    mr = images[doc["textures"][pbr["metallicRoughnessTexture"]["index"]]["source"]]
    want = np.rint(np.asarray(linear_to_srgb(tm.albedo)) * 255)
    assert np.abs(base.astype(float) - want).max() <= 1
    assert np.abs(mr[..., 1] / 255.0 - tm.roughness).max() <= 0.5 / 255 + 1e-6
    assert np.abs(mr[..., 2] / 255.0 - tm.metallic).max() <= 0.5 / 255 + 1e-6
    side = json.loads((tmp_path / "model.glb.json").read_text())
    assert np.allclose(side["scene_to_gltf"], SCENE_TO_GLTF) and side["scene_up"] == [0, 0, 1]
    assert np.isclose(np.linalg.det(SCENE_TO_GLTF), 1.0)


def test_open3d_loads_the_glb_with_its_textures(tmp_path, sphere_textured):
    _, tm = sphere_textured
    path = write_glb(tmp_path / "model.glb", tm)
    mesh = o3d.io.read_triangle_mesh(str(path), enable_post_processing=False)
    assert len(mesh.triangles) == tm.indices.shape[0]
    # Open3D reads the vertices as written (glTF frame)
    v = np.asarray(mesh.vertices)
    assert np.allclose(np.sort(v[:, 1]), np.sort(tm.positions[:, 2]), atol=1e-5)
    model = o3d.io.read_triangle_model(str(path))
    mat = model.materials[model.meshes[0].material_idx]
    assert mat.albedo_img is not None and np.asarray(mat.albedo_img).shape[:2] == (128, 128)
    assert np.asarray(mat.roughness_img).shape[:2] == (128, 128)
    assert np.isclose(mat.base_metallic, 1.0) and np.isclose(mat.base_roughness, 1.0)


def test_header_lengths(tmp_path, sphere_textured):
    _, tm = sphere_textured
    path = write_glb(tmp_path / "a.glb", tm)
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<4sII", data)
    assert (magic, version, length) == (b"glTF", 2, len(data)) and len(data) % 4 == 0


def test_the_diffuse_convention_travels_in_the_sidecar(tmp_path, sphere_textured):
    """``voxnero material`` names the diffuse lobe its base colour was fitted with; reading
    the file back gives renders the same lobe. A glTF without our sidecar (any other tool's)
    is glTF's own convention, "weighted"; a name no model has is refused."""
    import pytest

    from voxnero.asset.gltf import diffuse_sidecar, load_glb
    from voxnero.errors import ConfigError

    _, tm = sphere_textured
    p = write_glb(tmp_path / "a.glb", tm, sidecar=diffuse_sidecar("principled"))
    assert load_glb(p).diffuse == "principled"
    q = write_glb(tmp_path / "b.glb", tm)
    assert load_glb(q).diffuse == "weighted"
    (tmp_path / "b.glb.json").unlink()
    assert load_glb(q).diffuse == "weighted"
    with pytest.raises(ConfigError):
        diffuse_sidecar("lambert")
