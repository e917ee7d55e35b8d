"""Cameras (OpenCV convention) and ray generation."""
