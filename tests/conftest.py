"""Test-wide set-up.

Tests run with ``--import-mode=importlib`` (setup.cfg), so test files in different folders may
share a basename (``tests/shape/test_trainer.py`` and ``tests/material/test_trainer.py``).
``tests/`` is a package and setup.cfg's ``pythonpath = .`` puts the repository root on the
path: helper modules kept beside the tests are imported by their full name
(``from tests.fixtures.scenes import make_blender``,
``from tests.material.stage2_scene import sphere_geometry``).
"""

from __future__ import annotations

import torch

# One torch thread: on a 2-core machine most test tensors are small, and with two OpenMP
# threads element-wise kernels ran 15-40x slower whenever anything else used the CPU
# (docs/BENCHMARKS.md, "Shading core"). Trainers choose their own count (config `threads`).
torch.set_num_threads(1)
