"""Packaging: a wheel built from the repository carries the presets (``voxnero/configs/``), and
the package installed from it resolves ``--preset NAME`` outside the repository."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

from voxnero.config import CONFIG_DIR, available_presets, load_preset

REPO = Path(__file__).resolve().parent.parent


def test_presets_are_package_data():
    assert CONFIG_DIR == REPO / "voxnero" / "configs"
    assert {"tiny", "preview", "standard", "quality"} <= set(available_presets())
    # the repository's top-level configs/ still shows them
    assert sorted(p.name for p in (REPO / "configs").glob("*.yaml")) == \
        sorted(p.name for p in CONFIG_DIR.glob("*.yaml"))


def test_wheel_carries_the_presets_and_works_outside_the_repository(tmp_path):
    # build from a copy of what the wheel is made of (no build/ or egg-info in the repository)
    src = tmp_path / "src"
    src.mkdir()
    for name in ("setup.cfg", "pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    shutil.copytree(REPO / "voxnero", src / "voxnero",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation",
                        "-q", "-w", str(tmp_path / "dist"), str(src)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    wheel, = (tmp_path / "dist").glob("voxnero-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        z.extractall(tmp_path / "site")
    for preset in available_presets():
        assert f"voxnero/configs/{preset}.yaml" in names, preset
    # the unpacked wheel, imported from a folder outside the repository, finds its presets
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import voxnero.config as c; "
            "assert c.__file__.startswith(sys.argv[1]), c.__file__; "
            "import json; print(json.dumps({n: c.load_preset(n) for n in c.available_presets()}))")
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path / "site")], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(r.stdout) == {n: load_preset(n) for n in available_presets()}
