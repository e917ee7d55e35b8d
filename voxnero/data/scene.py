"""``Scene``, ``Split`` and ``Normalisation``: what every loader returns.

A scene's cameras, depths and points live in the *unit frame*, where the object lies inside the
unit sphere: ``x_unit = (x_input - center) / scale`` and ``x_input = x_unit * scale + center``
(no rotation, so directions and the up axis are unchanged). Outputs are written back in the
input frame with :meth:`Normalisation.to_input`.

How the normalisation is chosen (:func:`choose_normalisation`), first rule that applies:

1. ``bbox = (xmin, ymin, zmin, xmax, ymax, zmax)`` given (input frame): ``center`` = box centre,
   ``scale`` = half its diagonal (the box is inside the unit sphere).
2. ``radius`` and/or ``center`` given: ``scale = radius``; a missing one comes from rule 4
   (cameras), computed around the given/derived centre.
3. COLMAP scenes with sparse points (and no user values): the points seen by at least half the
   views and within median + 3 MAD of their median distance (:func:`robust_points`: walls, sky
   and stray tracks out), then the 2nd and 98th percentiles of those per axis give a box;
   ``center`` = its centre, ``scale`` = half its diagonal times 1.1 (margin).
4. Otherwise, from the cameras alone (assumes the cameras look at the object):

   * ``center`` = the least-squares point closest to all optical axes,
     ``argmin_p sum_i |(I - f_i f_i^T)(p - o_i)|^2`` for centres ``o_i`` and unit forward axes
     ``f_i``;
   * ``scale`` = the radius of the largest sphere around ``center`` that *every* view sees
     whole: camera i at distance ``d_i`` with narrowest half field of view ``theta_i``
     (smallest distance from the principal point to an image border, divided by the focal
     length, through ``atan``) sees a sphere of radius ``d_i sin(theta_i)`` whole, so
     ``scale = min_i d_i sin(theta_i)``.

   For the NeRF-synthetic dev scenes (distance 4, FOV 40 deg) this gives ``center`` = 0 and
   ``scale`` = 4 sin 20 deg = 1.368, so their radius-0.9 objects sit inside radius 0.66.

What was chosen (rule, centre, scale) is stored in ``scene.meta["normalisation"]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from voxnero.cameras.cameras import Cameras
from voxnero.errors import DataError


@dataclass
class Normalisation:
    """Similarity (translation + uniform scale) from the input frame to the unit frame.

    Attributes:
        center: ``(3,)`` input-frame point that maps to the origin.
        scale: input-frame length that maps to 1.
    """

    center: np.ndarray
    scale: float

    def __post_init__(self) -> None:
        self.center = np.asarray(self.center, dtype=np.float64).reshape(3)
        self.scale = float(self.scale)
        if not (self.scale > 0 and math.isfinite(self.scale)) or not np.isfinite(self.center).all():
            raise DataError(f"invalid normalisation center={self.center.tolist()} "
                            f"scale={self.scale}", fix="give a finite center and radius > 0")

    def _c(self, p):
        if isinstance(p, torch.Tensor):
            return torch.as_tensor(self.center, dtype=p.dtype, device=p.device)
        return self.center

    def to_unit(self, p):
        """Input-frame points ``(..., 3)`` -> unit frame, ``(p - center) / scale``."""
        return (p - self._c(p)) / self.scale

    def to_input(self, p):
        """Unit-frame points ``(..., 3)`` -> input frame, ``p * scale + center``."""
        return p * self.scale + self._c(p)

    def c2w_to_unit(self, c2w):
        """Map camera-to-world poses ``(..., 4, 4)`` into the unit frame (rotation unchanged)."""
        out = c2w.clone() if isinstance(c2w, torch.Tensor) else np.array(c2w, dtype=np.float64)
        out[..., :3, 3] = self.to_unit(out[..., :3, 3])
        return out

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly ``{"center": [x, y, z], "scale": s}``."""
        return {"center": [float(v) for v in self.center], "scale": self.scale}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Normalisation:
        """Inverse of :meth:`to_dict`."""
        return cls(np.asarray(d["center"], dtype=np.float64), float(d["scale"]))


@dataclass
class Split:
    """The images and cameras of one split (``train``, ``test`` ...), in the unit frame.

    Attributes:
        name: split name.
        images: ``(N, H, W, 3)`` float32 LINEAR RGB (alpha already composited, if any).
        cameras: ``Cameras`` in the unit frame.
        names: N image names (file stems).
        alpha: ``(N, H, W)`` float32 in [0, 1] if the input images had alpha, else None.
        masks: ``(N, H, W)`` float32 coverage in [0, 1]; EVALUATION ONLY, never an input.
        depth: ``(N, H, W)`` float32 z-depth along the camera's +z in the unit frame, 0 = none;
            EVALUATION ONLY.
    """

    name: str
    images: torch.Tensor
    cameras: Cameras
    names: list[str]
    alpha: torch.Tensor | None = None
    masks: torch.Tensor | None = None
    depth: torch.Tensor | None = None

    @property
    def n(self) -> int:
        return int(self.images.shape[0])

    @property
    def height(self) -> int:
        return int(self.images.shape[1])

    @property
    def width(self) -> int:
        return int(self.images.shape[2])


@dataclass
class Scene:
    """A loaded scene.

    Attributes:
        root: scene folder.
        format: ``"blender"``, ``"nero"``, ``"idr"`` or ``"colmap"``.
        splits: loaded splits by name.
        norm: input frame -> unit frame.
        up: ``(3,)`` unit world up axis (same in both frames).
        background: ``"alpha"`` if images carried alpha and were composited on a known colour,
            else ``"unknown"`` (e.g. a visible environment).
        meta: anything else the loader knows (``normalisation``, ``intrinsics``, ...).
    """

    root: Path
    format: str
    splits: dict[str, Split]
    norm: Normalisation
    up: np.ndarray
    background: str = "unknown"
    meta: dict[str, Any] = field(default_factory=dict)

    def split(self, name: str) -> Split:
        """The split ``name``; DataError listing the loaded ones if absent."""
        if name not in self.splits:
            raise DataError(f"split {name!r} is not loaded (have {sorted(self.splits)})",
                            path=self.root,
                            fix=f"load it with splits=(..., {name!r}) or check the scene files")
        return self.splits[name]

    def summary(self) -> str:
        """Human-readable multi-line description (what ``voxnero info`` prints)."""
        lines = [f"scene       {self.root}", f"format      {self.format}"]
        for s in self.splits.values():
            extras = [k for k in ("alpha", "masks", "depth") if getattr(s, k) is not None]
            lines.append(f"split       {s.name}: {s.n} views, {s.width}x{s.height}"
                         + (f" (+{', '.join(extras)})" if extras else ""))
            K = s.cameras.K
            if len(s.cameras):
                fx, fy, cx, cy = (float(K[:, 0, 0].mean()), float(K[:, 1, 1].mean()),
                                  float(K[:, 0, 2].mean()), float(K[:, 1, 2].mean()))
                same = bool(torch.allclose(K, K[:1].expand_as(K)))
                lines.append(f"  intrinsics fx={fx:.3f} fy={fy:.3f} cx={cx:.3f} cy={cy:.3f} px"
                             + ("" if same else " (mean; varies per view)"))
        n = self.meta.get("normalisation", {})
        lines.append(f"normalise   center={[round(float(v), 4) for v in self.norm.center]} "
                     f"scale={self.norm.scale:.4f} ({n.get('method', '?')})")
        lines.append(f"up          {[round(float(v), 4) for v in self.up]}")
        lines.append(f"background  {self.background}")
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# choosing the normalisation
# --------------------------------------------------------------------------------------------

def closest_point_to_axes(origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Least-squares point closest to lines ``o_i + t f_i``.

    Args:
        origins: ``(N, 3)`` points on the lines.
        dirs: ``(N, 3)`` directions (normalised here).

    Returns:
        ``(3,)`` point minimising the sum of squared distances; the mean of the origins when
        the lines are (near) parallel.
    """
    f = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    P = np.eye(3)[None] - f[:, :, None] * f[:, None, :]
    A = P.sum(0)
    b = np.einsum("nij,nj->i", P, origins)
    if np.linalg.cond(A) > 1e8:
        return origins.mean(0)
    return np.linalg.solve(A, b)


def narrow_half_fov(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """``(N,)`` half-angle of the largest cone around the optical axis inside each image.

    The smallest distance from the principal point to an image border, over the focal length
    of that axis, through ``atan`` (radians).
    """
    K = np.asarray(K, dtype=np.float64).reshape(-1, 3, 3)
    fx, fy, cx, cy = K[:, 0, 0], K[:, 1, 1], K[:, 0, 2], K[:, 1, 2]
    tx = np.minimum(cx, width - cx) / fx
    ty = np.minimum(cy, height - cy) / fy
    return np.arctan(np.clip(np.minimum(tx, ty), 1e-6, None))


def normalisation_from_cameras(c2w: np.ndarray, K: np.ndarray, width: int, height: int,
                               center: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Rule 4 of the module docstring: centre from the optical axes, radius every view sees.

    Args:
        c2w: ``(N, 4, 4)`` OpenCV camera-to-world, input frame.
        K: ``(N, 3, 3)`` intrinsics.
        width: image width.
        height: image height.
        center: use this centre instead of the axes' closest point.

    Returns:
        ``(center (3,), radius)``.
    """
    c2w = np.asarray(c2w, dtype=np.float64)
    o = c2w[:, :3, 3]
    if center is None:
        center = closest_point_to_axes(o, c2w[:, :3, 2])
    center = np.asarray(center, dtype=np.float64)
    d = np.linalg.norm(o - center, axis=1)
    r = float(np.min(d * np.sin(narrow_half_fov(K, width, height))))
    if not r > 0:
        raise DataError("cannot derive a scene radius from the cameras (a camera sits at the "
                        "scene centre?)", fix="give radius=R and center=[x,y,z] or bbox=[...]")
    return center, r


def robust_points(points: np.ndarray, c2w: np.ndarray, K: np.ndarray, width: int, height: int,
                  min_seen: float = 0.5) -> tuple[np.ndarray, dict[str, Any]]:
    """The sparse points that belong to the object's neighbourhood (rule 3).

    A point far off (a wall, the sky, a mismatched track) is seen by few of the views that
    circle an object, or lies far from the others: keep the points that project inside at least
    ``min_seen`` of the images (in front of the camera), then those within median + 3 MAD
    (scaled to a standard deviation) of their median distance to their median point.
    Either filter is skipped when it would leave fewer than 8 points.

    Returns:
        ``(kept points (M, 3), record {"points", "seen_by_half", "inliers"})``.
    """
    c2w = np.asarray(c2w, np.float64)
    K = np.asarray(K, np.float64).reshape(-1, 3, 3)
    seen = np.zeros(len(points))
    for i in range(len(c2w)):
        pc = (points - c2w[i, :3, 3]) @ c2w[i, :3, :3]
        z = pc[:, 2]
        uv = pc @ K[min(i, len(K) - 1)].T
        u, v = uv[:, 0] / np.maximum(z, 1e-12), uv[:, 1] / np.maximum(z, 1e-12)
        seen += (z > 0) & (u >= 0) & (u <= width) & (v >= 0) & (v <= height)
    p = points[seen >= min_seen * len(c2w)]
    if len(p) < 8:
        p = points
    n_seen = len(p)
    dist = np.linalg.norm(p - np.median(p, axis=0), axis=1)
    med = np.median(dist)
    mad = 1.4826 * np.median(np.abs(dist - med))
    q = p[dist <= med + 3.0 * mad]
    if len(q) >= 8:
        p = q
    return p, {"points": int(len(points)), "seen_by_half": int(n_seen), "inliers": int(len(p))}


def choose_normalisation(c2w: np.ndarray, K: np.ndarray, width: int, height: int,
                         points: np.ndarray | None = None, bbox=None, radius=None,
                         center=None) -> tuple[Normalisation, dict[str, Any]]:
    """Pick the normalisation by the rules of the module docstring.

    Args:
        c2w: ``(N, 4, 4)`` OpenCV camera-to-world in the input frame (all loaded views).
        K: ``(N, 3, 3)`` intrinsics.
        width: image width.
        height: image height.
        points: optional ``(P, 3)`` sparse points (COLMAP).
        bbox: optional ``(xmin, ymin, zmin, xmax, ymax, zmax)``.
        radius: optional scale.
        center: optional ``(3,)`` centre.

    Returns:
        The ``Normalisation`` and a JSON-friendly record for ``meta["normalisation"]``.
    """
    extra: dict[str, Any] = {}
    if bbox is not None:
        b = np.asarray(bbox, dtype=np.float64).reshape(-1)
        if b.size != 6 or not np.isfinite(b).all() or (b[3:] <= b[:3]).any():
            raise DataError(f"bbox={b.tolist()} is not (xmin, ymin, zmin, xmax, ymax, zmax) with "
                            "max > min", fix="give bbox=[xmin,ymin,zmin,xmax,ymax,zmax]")
        c = 0.5 * (b[:3] + b[3:])
        s = 0.5 * float(np.linalg.norm(b[3:] - b[:3]))
        method = "bbox (user): centre of the box, scale = half diagonal"
    elif radius is not None or center is not None:
        c_cam, r_cam = normalisation_from_cameras(c2w, K, width, height, center)
        c = c_cam
        s = float(radius) if radius is not None else r_cam
        method = ("user radius/center" + ("" if radius is not None and center is not None
                                          else " (rest from cameras)"))
    elif points is not None and len(points) >= 8:
        p, kept = robust_points(np.asarray(points, dtype=np.float64), c2w, K, width, height)
        lo, hi = np.percentile(p, 2, axis=0), np.percentile(p, 98, axis=0)
        c = 0.5 * (lo + hi)
        s = 0.55 * float(np.linalg.norm(hi - lo))
        method = ("sparse points seen by at least half the views, within median + 3 MAD of "
                  "their median distance: 2-98 percentile box, scale = 1.1 x half diagonal")
        extra = kept
    else:
        c, s = normalisation_from_cameras(c2w, K, width, height)
        method = "cameras: closest point to optical axes, largest sphere every view sees"
    norm = Normalisation(c, s)
    rec = {"method": method, **norm.to_dict(), **extra}
    if bbox is not None:
        rec["bbox"] = [float(v) for v in np.asarray(bbox).reshape(-1)]
    return norm, rec


# --------------------------------------------------------------------------------------------
# building splits (shared by the loaders)
# --------------------------------------------------------------------------------------------

def image_size(path: Path) -> tuple[int, int]:
    """``(width, height)`` of an image file from its header (cheap); DataError if unreadable."""
    from PIL import Image, UnidentifiedImageError

    if not Path(path).is_file():
        raise DataError("image file not found", path=path,
                        fix="check the file name in the scene's pose file and that the image "
                            "folder is complete")
    try:
        with Image.open(path) as im:
            return int(im.size[0]), int(im.size[1])
    except (OSError, UnidentifiedImageError) as e:
        raise DataError(f"cannot read image ({e})", path=path,
                        fix="re-export the image as an 8- or 16-bit PNG or a JPEG") from None


def load_image_stack(paths: list[Path], width: int, height: int, split: str,
                     threads: int = 4) -> np.ndarray:
    """Read images of one split and check they all have the expected size.

    Args:
        paths: image files.
        width: expected width.
        height: expected height.
        split: split name (for messages).
        threads: reader threads (Pillow releases the GIL while decoding).

    Returns:
        ``(N, H, W, C)`` float32 encoded values; ``C`` is the largest channel count found, grey
        is replicated to RGB and missing alpha is 1.
    """
    from concurrent.futures import ThreadPoolExecutor

    from voxnero.io.images import read_image

    if not paths:
        raise DataError(f"split {split!r} has no images", fix="add frames to the split")
    with ThreadPoolExecutor(max(1, min(threads, len(paths)))) as pool:
        imgs = list(pool.map(read_image, paths))
    channels = 4 if any(im.shape[2] == 4 for im in imgs) else 3
    out = np.empty((len(imgs), height, width, channels), dtype=np.float32)
    for i, (p, im) in enumerate(zip(paths, imgs, strict=True)):
        if im.shape[:2] != (height, width):
            raise DataError(f"image is {im.shape[1]}x{im.shape[0]} but split {split!r} expects "
                            f"{width}x{height} (mixed image sizes, or w/h in the pose file do "
                            "not match the images)", path=p,
                            fix="resize all images of a split to one size, or fix w/h in the "
                                "pose file")
        if im.shape[2] == 1:
            im = np.repeat(im, 3, axis=2)
        out[i, ..., :3] = im[..., :3]
        if channels == 4:
            out[i, ..., 3] = im[..., 3] if im.shape[2] == 4 else 1.0
    return out


def composite_linear(encoded: np.ndarray, white_bg: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """sRGB-decode ``(N, H, W, 3|4)`` images and composite alpha over a constant background.

    Compositing happens in linear space (``L = a * L_rgb + (1 - a) * bg``, bg = 1 for white,
    0 for black), as the straight (un-premultiplied) alpha of PNG intends. Images whose alpha is
    1 everywhere are treated as having no alpha.

    Returns:
        ``(linear (N, H, W, 3) float32, alpha (N, H, W) or None)``.
    """
    from voxnero.io.color import srgb_to_linear

    lin = srgb_to_linear(encoded[..., :3]).astype(np.float32)
    if encoded.shape[-1] < 4:
        return lin, None
    a = encoded[..., 3]
    if (a >= 1.0).all():
        return lin, None
    bg = 1.0 if white_bg else 0.0
    lin = lin * a[..., None] + (1.0 - a[..., None]) * bg
    return lin.astype(np.float32), a.astype(np.float32)


def load_masks(paths: list[Path], width: int, height: int, split: str) -> np.ndarray:
    """Read coverage masks (first channel, [0, 1]) as ``(N, H, W)`` float32 (evaluation only)."""
    stack = load_image_stack(paths, width, height, f"{split}_mask")
    return stack[..., 0]


def check_pose(mat, shape: tuple[int, int], where: str, path: Path) -> np.ndarray:
    """Validate one pose matrix: numeric, of ``shape`` (4x4 also accepted for 3x4), finite."""
    try:
        m = np.asarray(mat, dtype=np.float64)
    except (TypeError, ValueError):
        m = None
    if m is None or m.ndim != 2 or (m.shape != shape and not (shape == (3, 4)
                                                                 and m.shape == (4, 4))):
        got = "non-numeric" if m is None else f"shape {m.shape}"
        raise DataError(f"{where}: pose is {got}, expected a {shape[0]}x{shape[1]} matrix",
                        path=path, fix="fix or remove this frame's pose")
    if not np.isfinite(m).all():
        raise DataError(f"{where}: pose has non-finite values (NaN/Inf)", path=path,
                        fix="fix or remove this frame's pose")
    if m.shape == (4, 4) and shape == (3, 4):
        m = m[:3]
    return m


ORTHONORMAL_TOL = 1e-3
"""Largest entry of ``|R^T R - I|`` accepted for a camera rotation. Poses stored as float32 and
printed with 6-7 digits are off by ~1e-7; a rotation scaled or sheared by any visible amount
is off by far more (scaled x3: 8)."""

_POSE_FIX = ("fix or remove this frame's pose: a camera-to-world matrix is [R | t] with R a "
             "rotation (orthonormal columns, determinant +1) and, for 4x4, last row [0, 0, 0, 1]")


def check_camera(K, c2w, width: int, height: int, where: str, path: str | Path,
                 intrinsics_path: str | Path | None = None) -> None:
    """Refuse a camera that cannot make rays; every loader calls this for every frame, so
    ``voxnero info`` and the commands that train run the same checks.

    A camera passes when its pose is finite with an orthonormal, right-handed rotation
    (``|R^T R - I| <`` :data:`ORTHONORMAL_TOL`, ``det R > 0``; a 4x4 pose ends in
    ``[0, 0, 0, 1]``), its focal lengths are finite and > 0, its principal point lies strictly
    inside the image and ``K``'s last row is ``[0, 0, 1]``. Together these put both halves of the
    field of view, ``atan(cx / fx)`` and ``atan((W - cx) / fx)``, in (0°, 90°), so the field of
    view is in (0°, 180°). (A field of view given as an angle, ``camera_angle_x``, is checked by
    the Blender loader before it becomes a focal length.)

    Args:
        K: ``(3, 3)`` intrinsics in pixels (pixel centre +0.5).
        c2w: ``(4, 4)`` or ``(3, 4)`` OpenCV camera-to-world in the input frame.
        width: image width in pixels.
        height: image height in pixels.
        where: the frame, named in the error: index and image, e.g. ``"frame 3 (./train/r_3)"``.
        path: the pose file named in the error.
        intrinsics_path: the file holding the intrinsics when it is not ``path`` (COLMAP's
            cameras file).

    Raises:
        DataError: naming ``path``, ``where``, what is wrong and the fix.
    """
    K = np.asarray(K, dtype=np.float64)
    c2w = np.asarray(c2w, dtype=np.float64)
    kpath = path if intrinsics_path is None else intrinsics_path
    if not (width >= 1 and height >= 1):
        raise DataError(f"{where}: image size {width}x{height} is empty", path=kpath,
                        fix="give the image size in pixels (w, h >= 1) or drop w/h to read it "
                            "from the image")
    if not np.isfinite(K).all():
        raise DataError(f"{where}: intrinsics have non-finite values (NaN/Inf)", path=kpath,
                        fix="give finite focal lengths and principal point")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (fx > 0 and fy > 0):
        raise DataError(f"{where}: focal lengths fx={fx:g} fy={fy:g} must be > 0", path=kpath,
                        fix="give focal lengths in pixels (> 0), or a field of view in (0, pi) "
                            "radians")
    if np.abs(K[2] - (0.0, 0.0, 1.0)).max() > 1e-6 or abs(K[1, 0]) > 1e-6 * fy:
        raise DataError(f"{where}: intrinsics {K.round(6).tolist()} are not a pinhole matrix "
                        "[[fx, s, cx], [0, fy, cy], [0, 0, 1]]", path=kpath,
                        fix="store K in pixels with last row [0, 0, 1]")
    if not (0 < cx < width and 0 < cy < height):
        raise DataError(f"{where}: principal point ({cx:g}, {cy:g}) lies outside the "
                        f"{width}x{height} image", path=kpath,
                        fix="give cx in (0, w) and cy in (0, h), in pixels (the image centre "
                            "is (w/2, h/2))")
    if not np.isfinite(c2w).all():
        raise DataError(f"{where}: pose has non-finite values (NaN/Inf)", path=path,
                        fix=_POSE_FIX)
    R = c2w[:3, :3]
    det = float(np.linalg.det(R))
    if abs(det) < 1e-6:
        raise DataError(f"{where}: pose is singular (rotation determinant {det:.3g})",
                        path=path, fix=_POSE_FIX)
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > ORTHONORMAL_TOL:
        lengths = ", ".join(f"{v:.4g}" for v in np.linalg.norm(R, axis=0))
        raise DataError(f"{where}: rotation is not orthonormal (|R^T R - I| = {err:.3g}; "
                        f"column lengths {lengths}; scaled or sheared?)", path=path,
                        fix=_POSE_FIX)
    if det < 0:
        raise DataError(f"{where}: rotation has determinant {det:.4g} (a mirror, not a "
                        "rotation)", path=path, fix=_POSE_FIX + "; flip one axis back")
    if c2w.shape == (4, 4) and np.abs(c2w[3] - (0.0, 0.0, 0.0, 1.0)).max() > ORTHONORMAL_TOL:
        raise DataError(f"{where}: last row of the pose is {c2w[3].round(6).tolist()}, not "
                        "[0, 0, 0, 1] (a transposed matrix?)", path=path, fix=_POSE_FIX)


def make_split(name: str, encoded: np.ndarray, K: np.ndarray, c2w_input: np.ndarray,
               norm: Normalisation, names: list[str], white_bg: bool,
               masks: np.ndarray | None = None, depth_input: np.ndarray | None = None
               ) -> Split:
    """Assemble a ``Split`` in the unit frame from input-frame data.

    Args:
        name: split name.
        encoded: ``(N, H, W, 3|4)`` sRGB-encoded images (see :func:`load_image_stack`).
        K: ``(N, 3, 3)`` intrinsics (pixel centre +0.5).
        c2w_input: ``(N, 4, 4)`` OpenCV camera-to-world in the input frame.
        norm: the scene's normalisation.
        names: image names.
        white_bg: composite alpha on white (else black).
        masks: optional ``(N, H, W)`` coverage.
        depth_input: optional ``(N, H, W)`` z-depth in input units (0 = none).
    """
    lin, alpha = composite_linear(encoded, white_bg)
    n, h, w = lin.shape[:3]
    cams = Cameras(torch.from_numpy(np.asarray(K, np.float32)),
                   torch.from_numpy(norm.c2w_to_unit(c2w_input).astype(np.float32)), w, h)
    depth = None
    if depth_input is not None:
        depth = torch.from_numpy((np.asarray(depth_input, np.float64) / norm.scale)
                                 .astype(np.float32))
    return Split(name=name, images=torch.from_numpy(lin), cameras=cams, names=list(names),
                 alpha=None if alpha is None else torch.from_numpy(alpha),
                 masks=None if masks is None else torch.from_numpy(masks.astype(np.float32)),
                 depth=depth)
