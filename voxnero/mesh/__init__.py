"""Surfaces from grids: marching cubes (``extract``), Open3D clean-up (``cleanup``), mesh I/O in
the input frame (``io``)."""
