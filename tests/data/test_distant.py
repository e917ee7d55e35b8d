"""Background parallax measurement (voxnero/data/distant.py): an environment at infinity gives
no parallax, a plane near the region of interest gives a large one."""

from __future__ import annotations

import numpy as np
import torch

from tests.fixtures.cameras import look_at
from voxnero.cameras.cameras import Cameras
from voxnero.cameras.rays import image_rays
from voxnero.data.distant import distant_background_evidence
from voxnero.data.scene import Split


def _texture(p: np.ndarray) -> np.ndarray:
    """A smooth colour pattern of 2-D coordinates ``(..., 2)`` in [0, 1]."""
    return 0.5 + 0.4 * np.stack([np.sin(3 * p[..., 0]), np.cos(4 * p[..., 1]),
                                 np.sin(2 * p[..., 0] + 5 * p[..., 1])], -1)


def _split(near: bool, n: int = 12, w: int = 64, h: int = 48, f: float = 80.0,
           dist: float = 6.0) -> Split:
    rng = np.random.default_rng(0)
    eyes = []
    for _ in range(n):
        az, el = rng.uniform(0, 2 * np.pi), rng.uniform(0.3, 1.0)
        eyes.append(dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                    np.sin(el)]))
    c2w = torch.tensor(np.stack([look_at(e) for e in eyes]), dtype=torch.float32)
    K = torch.tensor([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]]).expand(n, 3, 3)
    cams = Cameras(K.clone(), c2w, w, h)
    imgs = []
    for i in range(n):
        o, d = (a.double().numpy() for a in image_rays(cams, i))
        if near:  # a textured round table z = -1.2, radius 6, in a constant room
            t = (-1.2 - o[..., 2]) / np.minimum(d[..., 2], -1e-6)
            p = o + t[..., None] * d
            table = (d[..., 2] < 0) & (np.linalg.norm(p[..., :2], axis=-1) < 6.0)
            col = np.where(table[..., None], _texture(p[..., :2] / 3.0), 0.8)
        else:  # the same texture on directions: an environment at infinity
            col = _texture(np.stack([np.arctan2(d[..., 0], d[..., 1]), d[..., 2]], -1))
        imgs.append(col)
    return Split("train", torch.tensor(np.stack(imgs), dtype=torch.float32), cams,
                 [str(i) for i in range(n)])


def test_distant_environment_has_no_parallax():
    ev = distant_background_evidence(_split(near=False), stride=1)
    assert ev["shared_fraction"] > 0.3
    assert ev["parallax_db"] < 3.0 and ev["env_fit_psnr"] > 25.0


def test_near_table_has_parallax():
    ev = distant_background_evidence(_split(near=True), stride=1)
    assert ev["parallax_db"] > 5.0 + 2.0  # adaptive.NEAR_PARALLAX_DB with a margin
