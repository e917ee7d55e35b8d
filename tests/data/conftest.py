"""Locate the dev scenes (the loaders' fixtures are in ``tests.fixtures.scenes``)."""

from __future__ import annotations

from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parents[1]
REPO = TESTS.parent
DEV_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def dev_data() -> Path:
    """``../shared/data`` relative to the repo root; skips when the dev scenes are absent."""
    if not (DEV_DATA / "sphere_gold" / "transforms_train.json").is_file():
        pytest.skip(f"dev scenes not found at {DEV_DATA} (shared data absent)")
    return DEV_DATA
