"""Exports of stage 2: textured glTF 2.0 / OBJ meshes, the env map as EXR, materials.json."""
