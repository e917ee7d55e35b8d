"""Helpers of the run-folder tests: tiny scenes, a tiny shape command line, folder snapshots."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.fixtures.scenes import make_blender
from voxnero import cli

SHAPE_FAST = ["--preset", "tiny", "--no-progress", "--no-eval", "iters=6", "mesh_res=16",
              "grid.init_candidates=[]", "grid.res=[8]", "grid.upsample_at=[]",
              "sampling.rays=64", "preview_every=0", "eval_every_s=0"]
"""A shape run of a second on the fixture scenes."""


def blender_scene(root: Path, n_train: int = 3, seed: int = 0) -> Path:
    """A tiny Blender scene of the analytic sphere (``tests/fixtures/scenes.py``)."""
    make_blender(root, n={"train": n_train, "test": 1}, seed=seed)
    return root


def shape_argv(scene: Path, out: Path, *extra: str) -> list[str]:
    return ["shape", str(scene), "--out", str(out), *SHAPE_FAST, *extra]


def run_cli(argv: list[str], capsys) -> tuple[int, str, str]:
    """``voxnero argv`` in process: (exit code, stdout, stderr); no traceback may leak."""
    try:
        rc = cli.main(argv)
    except Exception as e:  # noqa: BLE001 - a traceback is what is tested against
        out, err = capsys.readouterr()
        pytest.fail(f"{type(e).__name__} escaped the CLI: {e}\n{err[-2000:]}")
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err, err
    return rc, out, err


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (relative path -> bytes), hidden ones included."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def sdf_of(run: Path) -> np.ndarray:
    with np.load(run / "sdf.npz") as z:
        return z["sdf"].copy()
