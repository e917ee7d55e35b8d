"""Scenes: loaders for Blender/NeRF-synthetic, NeRO and COLMAP data, normalisation."""
