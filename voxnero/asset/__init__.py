"""Relightable assets: the asset in memory (``model.py``) and one module per file format, each
with its writer and its reader: ``gltf.py`` (``model.glb``), ``obj.py`` (``model.obj`` + MTL +
PNG), ``envmap.py`` (``envmap.exr`` + sidecar); ``textures.py`` bakes the UV atlas and textures the
mesh writers take, ``gt.py`` reads a scene's ground truth, ``load.py`` finds what a path holds."""
