"""The interactive window opens under a virtual X server (Xvfb) and closes by itself."""

from __future__ import annotations

import shutil
import subprocess
import sys

import pytest


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("xvfb-run") is None,
                    reason="xvfb-run not installed (apt package xvfb); the window needs a display")
def test_window_opens_under_xvfb(viewer_glb):
    r = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1024x768x24", sys.executable, "-m",
                        "voxnero", "view", str(viewer_glb), "--close-after", "2",
                        "--size", "320x240"], capture_output=True, text=True, timeout=300)
    out = r.stdout + r.stderr
    assert r.returncode == 0, out[-2000:]
    assert "[view] window" in out
    assert "Falling back to headless" not in out  # a real (virtual) display was used
