"""model.glb through the Khronos glTF-Validator (npm ``gltf-validator``, installed by ``make``
into ``.node/``): no errors, and the validator sees the PBR textures we wrote."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import pytest

from voxnero.asset.gltf import write_glb

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "tools" / "gltf_validate.js"
NODE = shutil.which("node")
INSTALLED = (ROOT / ".node" / "node_modules" / "gltf-validator").is_dir()

pytestmark = pytest.mark.skipif(
    NODE is None or not INSTALLED,
    reason="node or .node/node_modules/gltf-validator missing (make setup installs it with npm)")


def _validate(path: Path) -> tuple[int, dict]:
    r = subprocess.run([NODE, str(SCRIPT), str(path)], capture_output=True, text=True, timeout=60)
    assert r.returncode in (0, 1), r.stderr
    return r.returncode, json.loads(r.stdout)


def test_exported_glb_has_no_validator_errors(tmp_path, sphere_textured):
    _, tm = sphere_textured
    path = write_glb(tmp_path / "model.glb", tm)
    rc, report = _validate(path)
    errors = [m for m in report["issues"]["messages"] if m["severity"] == 0]
    assert rc == 0 and report["issues"]["numErrors"] == 0, errors
    info = report["info"]
    assert info["version"] == "2.0" and info["materialCount"] == 1
    assert info["hasTextures"] and info["drawCallCount"] == 1


def test_validator_catches_a_broken_file(tmp_path, sphere_textured):
    """The check can fail: a GLB whose declared length is wrong is reported as an error."""
    _, tm = sphere_textured
    path = write_glb(tmp_path / "model.glb", tm)
    data = bytearray(path.read_bytes())
    data[8:12] = (len(data) + 64).to_bytes(4, "little")
    bad = tmp_path / "bad.glb"
    bad.write_bytes(bytes(data))
    rc, report = _validate(bad)
    assert rc == 1 and report["issues"]["numErrors"] > 0
