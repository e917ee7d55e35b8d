"""VoxNeRO: explicit-voxel NeRO — posed photos of a shiny object to mesh, BRDF and light.

Data flow, one sub-package per step:
    data/ (images + poses -> Scene) -> cameras/ (rays) -> fields/ (SDF + feature grids)
    -> render/ (BRDF, split-sum, env maps, Monte Carlo) -> shape/ (stage 1 training)
    -> mesh/ (marching cubes, clean-up) -> material/ (stage 2) -> asset/ (glTF, OBJ, EXR:
    writers and readers)
    -> eval/ (metrics) and viewer/.
"""

__version__ = "0.1.0"
