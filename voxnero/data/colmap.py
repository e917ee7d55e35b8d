"""COLMAP sparse models: text and binary reader/writer, and the scene loader.

Layout: ``<scene>/sparse/0/{cameras,images,points3D}.{bin,txt}`` (or ``<scene>/sparse/`` or
the model files directly in ``<scene>``) and the images in ``<scene>/images/`` (or
``images_dir``). Binary files win when both exist.

Conventions: COLMAP poses are world-to-camera OpenCV (``x_cam = R(q) x_world + t``, quaternion
``(qw, qx, qy, qz)``), and COLMAP's pixel frame puts the centre of the top-left pixel at
(0.5, 0.5) — the project's own convention — so ``K`` is used as stored.

Camera models: ``SIMPLE_PINHOLE``, ``PINHOLE``, ``SIMPLE_RADIAL``, ``RADIAL``, ``OPENCV``.
Distorted models are **undistorted at load** onto a pinhole camera with the same ``fx, fy, cx,
cy`` and image size: each output pixel centre is mapped through the model's forward distortion
(kornia's ``distort_points``, the OpenCV polynomial ``k1, k2, p1, p2``, which is COLMAP's) and
the linear image is sampled bilinearly there; samples that fall outside the photo are black
(0). Masks get the same resampling. Any other model (fisheye, FOV, FULL_OPENCV ...) is refused
with a DataError saying to run ``colmap image_undistorter``.

Splits: all registered images are "train" unless ``split.json`` (split name -> list of image
names) sits in the scene folder. Up: the mean of the cameras' up vectors (``-y`` camera axis),
since COLMAP's world orientation is arbitrary.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from voxnero.data.scene import (
    Scene,
    check_camera,
    choose_normalisation,
    image_size,
    load_image_stack,
    load_masks,
    make_split,
)
from voxnero.errors import DataError

# model id -> (name, number of params), from COLMAP's camera model list
MODELS = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
    4: ("OPENCV", 8), 5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5),
    8: ("SIMPLE_RADIAL_FISHEYE", 4), 9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12),
}
MODEL_IDS = {name: (mid, n) for mid, (name, n) in MODELS.items()}
SUPPORTED = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
_UNDISTORT_FIX = ("undistort the images first: colmap image_undistorter --image_path images "
                  "--input_path sparse/0 --output_path undistorted --output_type COLMAP, then "
                  "load the 'undistorted' folder")


@dataclass
class ColmapCamera:
    """One COLMAP camera: ``model`` name, image ``width``/``height`` and raw ``params``."""

    id: int
    model: str
    width: int
    height: int
    params: np.ndarray


@dataclass
class ColmapImage:
    """One registered image: world-to-camera ``qvec (w, x, y, z)``, ``tvec``, camera, name."""

    id: int
    qvec: np.ndarray
    tvec: np.ndarray
    camera_id: int
    name: str
    xys: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point3d_ids: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.int64))


@dataclass
class ColmapModel:
    """A sparse model: cameras and images by id, points ``(P, 3)`` and colours ``(P, 3)``."""

    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points: np.ndarray
    colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    point_ids: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.int64))
    errors: np.ndarray = field(default_factory=lambda: np.zeros((0,)))


# --------------------------------------------------------------------------------------------
# maths
# --------------------------------------------------------------------------------------------

def qvec_to_rotmat(q: np.ndarray) -> np.ndarray:
    """Unit quaternion ``(w, x, y, z)`` (normalised here) -> ``(3, 3)`` rotation matrix."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotmat_to_qvec(R: np.ndarray) -> np.ndarray:
    """``(3, 3)`` rotation -> unit quaternion ``(w, x, y, z)`` with ``w >= 0``."""
    R = np.asarray(R, dtype=np.float64)
    # symmetric 4x4 whose top eigenvector is the quaternion (robust for all rotations)
    K = np.array([
        [R[0, 0] - R[1, 1] - R[2, 2], 0, 0, 0],
        [R[1, 0] + R[0, 1], R[1, 1] - R[0, 0] - R[2, 2], 0, 0],
        [R[2, 0] + R[0, 2], R[2, 1] + R[1, 2], R[2, 2] - R[0, 0] - R[1, 1], 0],
        [R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1], R[0, 0] + R[1, 1] + R[2, 2]],
    ]) / 3.0
    vals, vecs = np.linalg.eigh(K)
    x, y, z, w = vecs[:, np.argmax(vals)]
    q = np.array([w, x, y, z])
    return q if w >= 0 else -q


def camera_matrix(cam: ColmapCamera, path: Path | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole ``K (3, 3)`` and OpenCV distortion ``(k1, k2, p1, p2)`` of a supported model.

    ``path`` (the cameras file) is named in the error for an unsupported model.
    """
    p = cam.params
    if cam.model == "SIMPLE_PINHOLE":
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], (0, 0, 0, 0)
    elif cam.model == "PINHOLE":
        fx, fy, cx, cy, dist = p[0], p[1], p[2], p[3], (0, 0, 0, 0)
    elif cam.model == "SIMPLE_RADIAL":
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], (p[3], 0, 0, 0)
    elif cam.model == "RADIAL":
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], (p[3], p[4], 0, 0)
    elif cam.model == "OPENCV":
        fx, fy, cx, cy = p[:4]
        dist = tuple(p[4:8])
    else:
        raise DataError(f"camera {cam.id}: model {cam.model} is not supported "
                        f"(supported: {', '.join(SUPPORTED)})", path=path, fix=_UNDISTORT_FIX)
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dtype=np.float64)
    return K, np.asarray(dist, dtype=np.float64)


def undistort_images(images: torch.Tensor, K: torch.Tensor, dist: torch.Tensor) -> torch.Tensor:
    """Resample distorted images onto the pinhole camera ``K`` (same size).

    Args:
        images: ``(N, H, W, C)`` float (linear values, so interpolation is physical).
        K: ``(N, 3, 3)`` intrinsics (pixel centre +0.5), shared by input and output.
        dist: ``(N, 4)`` OpenCV coefficients ``(k1, k2, p1, p2)``.

    Returns:
        ``(N, H, W, C)``: output pixel centre ``q`` takes the bilinear sample of the input at
        ``distort(q)``; 0 outside the input.
    """
    from kornia.geometry.calibration import distort_points

    from voxnero.cameras.rays import pixel_centers

    n, h, w, _ = images.shape
    pts = pixel_centers(h, w).reshape(1, -1, 2).expand(n, -1, -1).to(images)
    src = distort_points(pts, K.to(images), dist.to(images))  # (N, HW, 2) pixel coords
    grid = torch.stack([src[..., 0] / w * 2 - 1, src[..., 1] / h * 2 - 1], -1)
    out = torch.nn.functional.grid_sample(images.permute(0, 3, 1, 2), grid.reshape(n, h, w, 2),
                                          mode="bilinear", padding_mode="zeros",
                                          align_corners=False)
    return out.permute(0, 2, 3, 1).contiguous()


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------

_OBS = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])
_TRACK = np.dtype([("image", "<i4"), ("point2d", "<i4")])


class _Reader:
    def __init__(self, path: Path):
        self.path, self.buf, self.pos = path, path.read_bytes(), 0

    def read(self, fmt: str):
        size = struct.calcsize("<" + fmt)
        if self.pos + size > len(self.buf):
            raise DataError(f"truncated binary file (wanted {size} bytes at offset {self.pos})",
                            path=self.path, fix="re-export the model from COLMAP")
        vals = struct.unpack_from("<" + fmt, self.buf, self.pos)
        self.pos += size
        return vals

    def array(self, dtype: np.dtype, count: int) -> np.ndarray:
        size = dtype.itemsize * count
        if self.pos + size > len(self.buf):
            raise DataError(f"truncated binary file (wanted {size} bytes at offset {self.pos})",
                            path=self.path, fix="re-export the model from COLMAP")
        arr = np.frombuffer(self.buf, dtype=dtype, count=count, offset=self.pos)
        self.pos += size
        return arr

    def cstring(self) -> str:
        end = self.buf.find(b"\x00", self.pos)
        if end < 0:
            raise DataError("truncated binary file (unterminated name)", path=self.path,
                            fix="re-export the model from COLMAP")
        s = self.buf[self.pos:end].decode("utf-8", "replace")
        self.pos = end + 1
        return s


def _text_lines(path: Path) -> list[str]:
    try:
        return [ln.rstrip("\n\r") for ln in path.read_text().splitlines()]
    except UnicodeDecodeError as e:
        raise DataError(f"not a text file ({e})", path=path, fix="re-export the model") from None


def _bad(path: Path, lineno: int, what: str) -> DataError:
    return DataError(f"line {lineno}: {what}", path=path,
                     fix="re-export the model with colmap model_converter --output_type TXT")


def read_cameras(path: Path) -> dict[int, ColmapCamera]:
    """Read ``cameras.txt`` or ``cameras.bin``. Unknown model names/ids raise DataError."""
    cams: dict[int, ColmapCamera] = {}
    if path.suffix == ".bin":
        r = _Reader(path)
        (n,) = r.read("Q")
        for _ in range(n):
            cid, mid, w, h = r.read("iiQQ")
            if mid not in MODELS:
                raise DataError(f"camera {cid}: unknown camera model id {mid}", path=path,
                                fix=_UNDISTORT_FIX)
            name, k = MODELS[mid]
            cams[cid] = ColmapCamera(cid, name, int(w), int(h), np.array(r.read("d" * k)))
        return cams
    for i, ln in enumerate(_text_lines(path), 1):
        if not ln.strip() or ln.lstrip().startswith("#"):
            continue
        parts = ln.split()
        try:
            cid, model, w, h = int(parts[0]), parts[1], int(parts[2]), int(parts[3])
            params = np.array([float(v) for v in parts[4:]])
        except (IndexError, ValueError):
            raise _bad(path, i, "expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS...") from None
        if model not in MODEL_IDS:
            raise DataError(f"line {i}: unknown camera model {model!r} (supported: "
                            f"{', '.join(SUPPORTED)})", path=path, fix=_UNDISTORT_FIX)
        if len(params) != MODEL_IDS[model][1]:
            raise _bad(path, i, f"{model} needs {MODEL_IDS[model][1]} parameters, got "
                                f"{len(params)}")
        cams[cid] = ColmapCamera(cid, model, w, h, params)
    return cams


def read_images(path: Path) -> dict[int, ColmapImage]:
    """Read ``images.txt`` or ``images.bin`` (poses and 2D observations)."""
    imgs: dict[int, ColmapImage] = {}
    if path.suffix == ".bin":
        r = _Reader(path)
        (n,) = r.read("Q")
        for _ in range(n):
            iid, qw, qx, qy, qz, tx, ty, tz, cid = r.read("idddddddi")
            name = r.cstring()
            (npts,) = r.read("Q")
            obs = r.array(_OBS, npts)
            imgs[iid] = ColmapImage(iid, np.array([qw, qx, qy, qz]), np.array([tx, ty, tz]),
                                    cid, name, np.stack([obs["x"], obs["y"]], -1),
                                    obs["id"].astype(np.int64))
        return imgs
    lines = _text_lines(path)
    i = 0
    while i < len(lines):
        ln = lines[i]
        i += 1
        if not ln.strip() or ln.lstrip().startswith("#"):
            continue
        parts = ln.split()
        try:
            iid = int(parts[0])
            q = np.array([float(v) for v in parts[1:5]])
            t = np.array([float(v) for v in parts[5:8]])
            cid = int(parts[8])
            name = " ".join(parts[9:])
            if len(q) != 4 or len(t) != 3 or not name:
                raise ValueError
        except (IndexError, ValueError):
            raise _bad(path, i, "expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME") from None
        pts_line = lines[i] if i < len(lines) else ""
        i += 1
        vals = pts_line.split()
        try:
            arr = np.array([float(v) for v in vals]).reshape(-1, 3) if vals else np.zeros((0, 3))
        except ValueError:
            raise _bad(path, i, "expected X Y POINT3D_ID triples") from None
        imgs[iid] = ColmapImage(iid, q, t, cid, name, arr[:, :2], arr[:, 2].astype(np.int64))
    return imgs


def read_points3d(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Read ``points3D.txt`` / ``.bin``: ids ``(P,)``, xyz ``(P, 3)``, rgb ``(P, 3)``, error."""
    ids, xyz, rgb, err = [], [], [], []
    if path.suffix == ".bin":
        r = _Reader(path)
        (n,) = r.read("Q")
        for _ in range(n):
            pid, x, y, z, cr, cg, cb, e, tl = r.read("QdddBBBdQ")
            r.array(_TRACK, tl)
            ids.append(pid)
            xyz.append((x, y, z))
            rgb.append((cr, cg, cb))
            err.append(e)
    else:
        for i, ln in enumerate(_text_lines(path), 1):
            if not ln.strip() or ln.lstrip().startswith("#"):
                continue
            parts = ln.split()
            try:
                ids.append(int(parts[0]))
                xyz.append(tuple(float(v) for v in parts[1:4]))
                rgb.append(tuple(int(v) for v in parts[4:7]))
                err.append(float(parts[7]))
            except (IndexError, ValueError):
                raise _bad(path, i, "expected POINT3D_ID X Y Z R G B ERROR TRACK...") from None
    return (np.asarray(ids, np.int64), np.asarray(xyz, np.float64).reshape(-1, 3),
            np.asarray(rgb, np.uint8).reshape(-1, 3), np.asarray(err, np.float64))


def _model_file(folder: Path, stem: str) -> Path | None:
    for ext in (".bin", ".txt"):
        if (folder / f"{stem}{ext}").is_file():
            return folder / f"{stem}{ext}"
    return None


def read_model(folder: str | Path) -> ColmapModel:
    """Read a sparse model folder (binary files preferred over text)."""
    folder = Path(folder)
    cp, ip = _model_file(folder, "cameras"), _model_file(folder, "images")
    if cp is None or ip is None:
        raise DataError("COLMAP model needs cameras.{bin,txt} and images.{bin,txt}",
                        path=folder, fix="point to the sparse/0 folder of a COLMAP project")
    cams, imgs = read_cameras(cp), read_images(ip)
    pp = _model_file(folder, "points3D")
    if pp is not None:
        pid, xyz, rgb, err = read_points3d(pp)
    else:
        pid, xyz, rgb, err = (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3), np.uint8),
                              np.zeros(0))
    return ColmapModel(cams, imgs, xyz, rgb, pid, err)


# --------------------------------------------------------------------------------------------
# writing (used to build test fixtures and to export poses)
# --------------------------------------------------------------------------------------------

def write_model(model: ColmapModel, folder: str | Path, binary: bool = False) -> None:
    """Write ``cameras``, ``images`` and ``points3D`` in COLMAP's text or binary format."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if binary:
        b = bytearray(struct.pack("<Q", len(model.cameras)))
        for c in model.cameras.values():
            b += struct.pack("<iiQQ", c.id, MODEL_IDS[c.model][0], c.width, c.height)
            b += struct.pack("<" + "d" * len(c.params), *c.params)
        (folder / "cameras.bin").write_bytes(bytes(b))
        b = bytearray(struct.pack("<Q", len(model.images)))
        for im in model.images.values():
            b += struct.pack("<idddddddi", im.id, *im.qvec, *im.tvec, im.camera_id)
            b += im.name.encode() + b"\x00" + struct.pack("<Q", len(im.xys))
            for (x, y), pid in zip(im.xys, im.point3d_ids, strict=True):
                b += struct.pack("<ddq", x, y, int(pid))
        (folder / "images.bin").write_bytes(bytes(b))
        b = bytearray(struct.pack("<Q", len(model.points)))
        for k, p in enumerate(model.points):
            b += struct.pack("<QdddBBBdQ", int(model.point_ids[k]), *p, *model.colors[k],
                             float(model.errors[k]), 0)
        (folder / "points3D.bin").write_bytes(bytes(b))
        return
    lines = ["# Camera list: CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    for c in model.cameras.values():
        lines.append(" ".join([str(c.id), c.model, str(c.width), str(c.height)]
                              + [repr(float(v)) for v in c.params]))
    (folder / "cameras.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list: IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for im in model.images.values():
        lines.append(" ".join([str(im.id)] + [repr(float(v)) for v in (*im.qvec, *im.tvec)]
                              + [str(im.camera_id), im.name]))
        lines.append(" ".join(f"{float(x)!r} {float(y)!r} {int(p)}"
                              for (x, y), p in zip(im.xys, im.point3d_ids, strict=True)))
    (folder / "images.txt").write_text("\n".join(lines) + "\n")
    lines = ["# 3D point list: POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[]"]
    for k, p in enumerate(model.points):
        c = model.colors[k]
        x, y, z = (repr(float(v)) for v in p)
        lines.append(f"{int(model.point_ids[k])} {x} {y} {z} "
                     f"{int(c[0])} {int(c[1])} {int(c[2])} {float(model.errors[k])!r}")
    (folder / "points3D.txt").write_text("\n".join(lines) + "\n")


# --------------------------------------------------------------------------------------------
# scene loader
# --------------------------------------------------------------------------------------------

def find_model_dir(root: Path) -> Path | None:
    """The sparse model folder of a scene: ``sparse/0``, ``sparse`` or ``root`` itself."""
    for cand in (root / "sparse" / "0", root / "sparse", root):
        if _model_file(cand, "cameras") is not None and _model_file(cand, "images") is not None:
            return cand
    return None


def is_colmap(root: Path) -> bool:
    """True if ``root`` holds a COLMAP sparse model (see :func:`find_model_dir`)."""
    return find_model_dir(root) is not None


def _images_dir(root: Path, model_dir: Path, images_dir) -> Path:
    if images_dir is not None:
        return Path(images_dir)
    for cand in (root / "images", model_dir.parent.parent / "images", model_dir / "images"):
        if cand.is_dir():
            return cand
    return root / "images"


def load_colmap(root: str | Path, splits=("train",), white_bg: bool = False, radius=None,
                center=None, bbox=None, eval_extras: bool = False, images_dir=None) -> Scene:
    """Load a COLMAP scene (see the module docstring).

    With ``eval_extras``, ``<scene>/<split>_mask/<image stem>.png`` masks are loaded when
    present (undistorted like the images).
    """
    root = Path(root)
    mdir = find_model_dir(root)
    if mdir is None:
        raise DataError("no COLMAP model (cameras/images .bin/.txt)", path=root,
                        fix="point to a COLMAP project with sparse/0/")
    model = read_model(mdir)
    if not model.images:
        raise DataError("COLMAP model has no registered images", path=mdir,
                        fix="run the COLMAP mapper again; no image was registered")
    img_dir = _images_dir(root, mdir, images_dir)
    order = sorted(model.images.values(), key=lambda im: im.name)
    Ks, dists, c2ws, sizes = {}, {}, {}, {}
    for im in order:
        cam = model.cameras.get(im.camera_id)
        if cam is None:
            raise DataError(f"image {im.name!r} uses camera {im.camera_id}, which is not in "
                            "the cameras file", path=mdir, fix="re-export the model")
        K, dist = camera_matrix(cam, _model_file(mdir, "cameras"))
        if not (np.isfinite(im.qvec).all() and np.isfinite(im.tvec).all()
                and np.linalg.norm(im.qvec) > 0):
            raise DataError(f"image {im.name!r}: non-finite or zero pose", path=mdir,
                            fix="remove the image from the model or re-run the mapper")
        R = qvec_to_rotmat(im.qvec)
        c2w = np.eye(4)
        c2w[:3, :3] = R.T
        c2w[:3, 3] = -R.T @ im.tvec
        check_camera(K, c2w, cam.width, cam.height, f"image {im.id} ({im.name})",
                     _model_file(mdir, "images"), intrinsics_path=_model_file(mdir, "cameras"))
        Ks[im.name], dists[im.name], c2ws[im.name] = K, dist, c2w
        sizes[im.name] = (cam.width, cam.height)
    names_all = [im.name for im in order]
    if len(set(sizes.values())) > 1:
        bad = next(n for n in names_all if sizes[n] != sizes[names_all[0]])
        raise DataError(f"image {bad!r} is {sizes[bad][0]}x{sizes[bad][1]} but "
                        f"{names_all[0]!r} is {sizes[names_all[0]][0]}x"
                        f"{sizes[names_all[0]][1]} (mixed image sizes)", path=mdir,
                        fix="resize/undistort all images to one size "
                            "(colmap image_undistorter)")
    w, h = sizes[names_all[0]]
    K_all = np.stack([Ks[n] for n in names_all])
    c2w_all = np.stack([c2ws[n] for n in names_all])
    pts = model.points if len(model.points) else None
    norm, rec = choose_normalisation(c2w_all, K_all, w, h, points=pts, bbox=bbox,
                                     radius=radius, center=center)
    up = -c2w_all[:, :3, 1].mean(0)
    up = up / max(np.linalg.norm(up), 1e-12)

    split_file = root / "split.json"
    out, any_alpha, undistorted = {}, False, False
    for s in splits:
        if split_file.is_file():
            try:
                names = [str(v) for v in json.loads(split_file.read_text())[s]]
            except (json.JSONDecodeError, KeyError, TypeError) as e:
                raise DataError(f"split {s!r} not readable ({e!r})", path=split_file,
                                fix='split.json maps split names to image names, e.g. '
                                    '{"train": ["a.jpg"], "test": ["b.jpg"]}') from None
            missing = [n for n in names if n not in Ks]
            if missing:
                raise DataError(f"split {s!r} lists images not in the model: {missing[:5]}",
                                path=split_file, fix="remove them or re-run the mapper")
        elif s == "train":
            names = names_all
        else:
            raise DataError(f"split {s!r} asked for, but the scene has no split list (every "
                            "image is 'train')", path=root,
                            fix=f'write {split_file} like {{"train": [...], "{s}": [...]}}')
        if not names:
            raise DataError(f"split {s!r} is empty", path=split_file, fix="list some images")
        paths = [img_dir / n for n in names]
        for p, n in zip(paths, names, strict=True):
            if image_size(p) != sizes[n]:
                raise DataError(f"image is {image_size(p)[0]}x{image_size(p)[1]} but its "
                                f"COLMAP camera says {sizes[n][0]}x{sizes[n][1]}", path=p,
                                fix="use the images the model was built from")
        enc = load_image_stack(paths, w, h, s)
        masks = None
        mdir_s = root / f"{s}_mask"
        if eval_extras and mdir_s.is_dir():
            masks = load_masks([mdir_s / f"{Path(n).stem}.png" for n in names], w, h, s)
        idx = [names_all.index(n) for n in names]
        sp = make_split(s, enc, K_all[idx], c2w_all[idx], norm, [Path(n).stem for n in names],
                        white_bg, masks, None)
        dist = torch.from_numpy(np.stack([dists[n] for n in names]).astype(np.float32))
        if bool((dist != 0).any()):
            Kt = sp.cameras.K
            sp.images = undistort_images(sp.images, Kt, dist)
            if sp.alpha is not None:
                sp.alpha = undistort_images(sp.alpha[..., None], Kt, dist)[..., 0]
            if sp.masks is not None:
                sp.masks = undistort_images(sp.masks[..., None], Kt, dist)[..., 0]
            undistorted = True
        any_alpha |= sp.alpha is not None
        out[s] = sp
    models = sorted({model.cameras[im.camera_id].model for im in order})
    return Scene(root=root, format="colmap", splits=out, norm=norm, up=up,
                 background="alpha" if any_alpha else "unknown",
                 meta={"normalisation": rec, "up_method": "mean camera up (-y) vector",
                       "white_bg": bool(white_bg), "model_dir": str(mdir),
                       "images_dir": str(img_dir), "camera_models": models,
                       "undistorted": undistorted, "n_points": int(len(model.points))})
