"""Open3D viewer: the asset per channel, camera frusta, headless screenshots, a window."""
