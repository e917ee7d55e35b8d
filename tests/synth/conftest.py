"""Shared settings of the synth tests."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """Run on one torch thread, as ``voxnero synth`` does (threads=1): the tracer's ~10⁵-element
    ops gain little from intra-op threads, and on the shared 2-core machine they were 6x slower."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
