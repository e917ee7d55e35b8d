"""Test-wide set-up.

Tests run with ``--import-mode=importlib`` (setup.cfg), so test files in different folders may
share a basename (``tests/shape/test_trainer.py`` and ``tests/material/test_trainer.py``).
Small helper modules kept beside the tests (e.g. ``tests/material/stage2_scene.py``,
``tests/fixtures/``) are imported by plain name, so ``tests/`` and each of its sub-folders are
put on ``sys.path`` here; give such helper modules unique names.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

_TESTS = Path(__file__).resolve().parent
for _d in [_TESTS, *sorted(p for p in _TESTS.iterdir()
                           if p.is_dir() and not p.name.startswith((".", "_")))]:
    if str(_d) not in sys.path:
        sys.path.append(str(_d))

# One torch thread: on a 2-core machine most test tensors are small, and with two OpenMP
# threads element-wise kernels ran 15-40x slower whenever anything else used the CPU
# (docs/BENCHMARKS.md, "Shading core"). Trainers choose their own count (config `threads`).
torch.set_num_threads(1)
