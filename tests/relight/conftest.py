"""Fixtures of the relight tests."""

from tests.fixtures.assets import sphere_asset_files  # noqa: F401 (a fixture)
