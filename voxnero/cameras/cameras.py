"""Pinhole cameras in one internal convention (OpenCV) and converters from other conventions.

Convention (binding for the whole project):

* ``c2w (N, 4, 4)``: camera-to-world, OpenCV camera axes: x right, y down, z forward (the camera
  looks down +z).
* ``K (N, 3, 3)``: intrinsics in pixels. Pixel (column i, row j) covers ``[i, i+1] x [j, j+1]``
  and its centre is ``(i + 0.5, j + 0.5)``; a camera-space point ``(x, y, z)`` projects to
  ``u = fx x / z + cx``, ``v = fy y / z + cy`` (continuous pixel coordinates, u = column).
* Blender / OpenGL poses (x right, y up, looking down -z) convert by right-multiplying by
  ``diag(1, -1, -1, 1)`` (:func:`opengl_to_opencv`), an involution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

_FLIP_YZ = (1.0, -1.0, -1.0, 1.0)


def _flip(c2w):
    if isinstance(c2w, torch.Tensor):
        return c2w * torch.tensor(_FLIP_YZ, dtype=c2w.dtype, device=c2w.device)
    c2w = np.asarray(c2w)
    return c2w * np.asarray(_FLIP_YZ, dtype=c2w.dtype if c2w.dtype.kind == "f" else np.float64)


def opengl_to_opencv(c2w_gl):
    """OpenGL/Blender camera-to-world ``(..., 4, 4)`` -> OpenCV camera-to-world (numpy or torch).

    ``c2w_cv = c2w_gl @ diag(1, -1, -1, 1)``: the camera's y and z axes flip, the centre stays.
    """
    return _flip(c2w_gl)


def opencv_to_opengl(c2w_cv):
    """OpenCV camera-to-world ``(..., 4, 4)`` -> OpenGL/Blender (the same flip; it is its own
    inverse)."""
    return _flip(c2w_cv)


def w2c_to_c2w(w2c):
    """Invert rigid world-to-camera poses ``(..., 3, 4)`` or ``(..., 4, 4)`` -> ``(..., 4, 4)``.

    Uses ``R^T`` and ``-R^T t`` (exact for rotations). numpy or torch.
    """
    if isinstance(w2c, torch.Tensor):
        R, t = w2c[..., :3, :3], w2c[..., :3, 3:4]
        Rt = R.transpose(-1, -2)
        top = torch.cat([Rt, -Rt @ t], dim=-1)
        bottom = torch.zeros(*top.shape[:-2], 1, 4, dtype=top.dtype, device=top.device)
        bottom[..., 0, 3] = 1
        return torch.cat([top, bottom], dim=-2)
    w2c = np.asarray(w2c, dtype=np.float64)
    R, t = w2c[..., :3, :3], w2c[..., :3, 3:4]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros(w2c.shape[:-2] + (4, 4))
    out[..., :3, :3] = Rt
    out[..., :3, 3:4] = -Rt @ t
    out[..., 3, 3] = 1
    return out


def _tensor(x) -> torch.Tensor:
    if isinstance(x, torch.Tensor):
        return x.to(torch.float32)
    return torch.as_tensor(np.asarray(x, dtype=np.float32))


@dataclass
class Cameras:
    """A batch of N pinhole cameras of one image size, OpenCV convention.

    Attributes:
        K: ``(N, 3, 3)`` float32 intrinsics in pixels (pixel centre at +0.5).
        c2w: ``(N, 4, 4)`` float32 camera-to-world, OpenCV axes (x right, y down, z forward).
        width: image width in pixels.
        height: image height in pixels.
    """

    K: torch.Tensor
    c2w: torch.Tensor
    width: int
    height: int

    def __post_init__(self) -> None:
        self.K = _tensor(self.K)
        self.c2w = _tensor(self.c2w)
        if self.K.ndim == 2:
            self.K = self.K[None]
        if self.c2w.ndim == 2:
            self.c2w = self.c2w[None]
        if self.c2w.shape[-2:] == (3, 4):
            pad = torch.zeros(*self.c2w.shape[:-2], 1, 4, dtype=self.c2w.dtype,
                              device=self.c2w.device)
            pad[..., 0, 3] = 1
            self.c2w = torch.cat([self.c2w, pad], dim=-2)
        if self.K.shape[-2:] != (3, 3) or self.c2w.shape[-2:] != (4, 4):
            raise ValueError(f"Cameras needs K (N,3,3) and c2w (N,4,4); got {tuple(self.K.shape)}"
                             f" and {tuple(self.c2w.shape)}")
        if self.K.shape[0] != self.c2w.shape[0]:
            if self.K.shape[0] == 1:
                self.K = self.K.expand(self.c2w.shape[0], 3, 3).clone()
            else:
                raise ValueError(f"{self.K.shape[0]} intrinsics for {self.c2w.shape[0]} poses")
        self.width, self.height = int(self.width), int(self.height)

    def __len__(self) -> int:
        return int(self.c2w.shape[0])

    def __getitem__(self, idx) -> Cameras:
        """Select cameras by int, slice, list or index/bool tensor; always returns ``Cameras``."""
        if isinstance(idx, (int, np.integer)):
            if not -len(self) <= idx < len(self):
                raise IndexError(f"camera {idx} out of range for {len(self)} cameras")
            idx = slice(int(idx) % len(self), int(idx) % len(self) + 1)
        if isinstance(idx, list):
            idx = torch.as_tensor(idx, dtype=torch.long)
        if isinstance(idx, torch.Tensor):
            idx = idx.to(self.c2w.device)
            if idx.ndim == 0:
                idx = idx[None]
        return Cameras(self.K[idx], self.c2w[idx], self.width, self.height)

    def to(self, device: torch.device | str) -> Cameras:
        """Copy to ``device``."""
        return Cameras(self.K.to(device), self.c2w.to(device), self.width, self.height)

    @property
    def device(self) -> torch.device:
        return self.c2w.device

    @property
    def centers(self) -> torch.Tensor:
        """``(N, 3)`` camera centres in world coordinates."""
        return self.c2w[:, :3, 3]

    @property
    def w2c(self) -> torch.Tensor:
        """``(N, 4, 4)`` world-to-camera (OpenCV), the rigid inverse of ``c2w``."""
        return w2c_to_c2w(self.c2w)

    @property
    def forward(self) -> torch.Tensor:
        """``(N, 3)`` unit viewing directions (camera +z) in world coordinates."""
        return torch.nn.functional.normalize(self.c2w[:, :3, 2], dim=-1)

    def project(self, points: torch.Tensor, cam: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Project world points into camera ``cam``.

        Args:
            points: ``(M, 3)`` world points.
            cam: camera index.

        Returns:
            ``uv (M, 2)`` continuous pixel coordinates (column, row; a pixel centre is at
            +0.5) and ``z (M,)`` depth along the camera's +z axis (negative: behind).
        """
        points = _tensor(points).to(self.device)
        w2c = self.w2c[cam]
        pc = points @ w2c[:3, :3].T + w2c[:3, 3]
        z = pc[:, 2]
        K = self.K[cam]
        uv = (pc @ K.T)[:, :2] / z[:, None]
        return uv, z


def look_at_opencv(eyes: np.ndarray, target: np.ndarray | None = None,
                   up: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera-to-world matrices (N, 4, 4) looking from ``eyes`` (N, 3) at ``target``.

    Columns: x right = normalize(forward × up), y down = forward × x, z forward, centre.
    Where forward is parallel to ``up`` the world +Y is used as up instead (no roll otherwise).
    """
    eyes = np.asarray(eyes, dtype=np.float64)
    target = np.zeros(3) if target is None else np.asarray(target, dtype=np.float64)
    fwd = target - eyes
    fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
    up_v = np.broadcast_to(np.asarray(up, dtype=np.float64), fwd.shape).copy()
    x = np.cross(fwd, up_v)
    bad = np.linalg.norm(x, axis=1) < 1e-9
    if bad.any():
        x[bad] = np.cross(fwd[bad], np.array([0.0, 1.0, 0.0]))
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(fwd, x)
    c2w = np.tile(np.eye(4), (len(eyes), 1, 1))
    c2w[:, :3, 0], c2w[:, :3, 1], c2w[:, :3, 2], c2w[:, :3, 3] = x, y, fwd, eyes
    return c2w
