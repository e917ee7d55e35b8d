"""Shared fixtures of the shading-core tests."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """Run each test on one intra-op thread: on the shared 2-core machine two OpenMP threads
    made element-wise kernels ~20x slower under load (measured: 64 ms vs 3.4 ms for a 120k x 3
    reduction). Restored after the test. Also seeds torch's global generator."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    torch.manual_seed(0)  # tests drawing from the global generator are deterministic
    yield
    torch.set_num_threads(before)

