"""The learned environment map as OpenEXR plus a sidecar JSON naming its convention."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from voxnero.io.exr import write_exr

CONVENTION = {
    "projection": "equirectangular (latitude-longitude), linear HDR RGB radiance",
    "up": "+Z of the scene's input frame",
    "direction": "unit world direction d from the object toward the environment",
    "u": "atan2(dx, dy) / (2 pi), wrapped to [0, 1)",
    "v": "arccos(dz) / pi",
    "pixel": "x = u * W - 0.5 (periodic), y = v * (H - 1) (clamped); row 0 = zenith, "
             "row H-1 = nadir, u = 0.25 toward +X, u = 0.5 toward -Y",
    "pixel_centre_direction": "theta = pi * j / (H - 1), phi = 2 pi (i + 0.5) / W, "
                              "d = (sin theta sin phi, sin theta cos phi, cos theta)",
    "same_as": "the dev scenes' Mitsuba envmap with to_world = rotate(+X, 90 deg)",
}


def write_envmap(path: str | Path, image: np.ndarray, extra: dict | None = None) -> Path:
    """Write ``envmap.exr`` (float32 RGB) and ``envmap.json`` beside it.

    Args:
        path: the ``.exr`` file.
        image: (H, W, 3) linear radiance (numpy or torch), W = 2H.
        extra: more sidecar entries (e.g. the scene's up axis, how the map was made).

    Returns:
        The EXR path.
    """
    if hasattr(image, "detach"):
        image = image.detach().cpu().numpy()
    image = np.asarray(image, dtype=np.float32)
    path = Path(path)
    write_exr(path, image, half=False)
    meta = {"file": path.name, "height": int(image.shape[0]), "width": int(image.shape[1]),
            "convention": CONVENTION,
            "units": "linear radiance on the scale of the input images (1 = sRGB white)"}
    meta.update(extra or {})
    path.with_suffix(".json").write_text(json.dumps(meta, indent=1))
    return path
