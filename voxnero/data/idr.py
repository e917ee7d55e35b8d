"""Loader of the NeuS / IDR layout (how NeuS, IDR, Voxurf and NeuS2 distribute DTU and BlendedMVS).

Format (one folder per capture)::

    image/ or images/     photos, any names; the i-th in sorted order is view i
    mask/ or masks/       optional object masks, same count and order (first channel, > 0.5)
    cameras_sphere.npz    (or cameras.npz) world_mat_i: K [R | t] as a 4x4 projection from the
                          world frame to pixels; scale_mat_i: maps the unit sphere (the region
                          of interest) into the world frame; optional camera_mat_i (ignored)

Projection of a unit-sphere point ``X`` into view i: ``world_mat_i @ scale_mat_i @ X``
(homogeneous, divide by the third coordinate). The projection is split here into an OpenCV
``K`` and ``c2w`` by an RQ decomposition, in the **world frame** of the capture: that is the
input frame, so outputs (``mesh.ply``, ``model.glb``) line up with the capture's own data.

Pixel convention: IDR/NeuS put pixel centres at integer coordinates (their rays go through
``(i, j)``), VoxNeRO at ``i + 0.5``: the principal point is shifted by +0.5 at load.

Region of interest: the unit sphere of ``scale_mat`` (one per view, all equal in practice; the
first is used and the others checked), so ``Normalisation(center = scale_mat[:3, 3], scale =
scale_mat[0, 0])``; ``bbox=`` / ``center=`` / ``radius=`` override it like for every format.

Splits (no split list ships with the format): the DTU/NeuS convention, **views whose index
% 8 == 0 are held out** as ``"test"``, the others are ``"train"``; ``"all"`` is every view. A
``split.json`` in the folder mapping split names to view indices replaces that.

Masks are evaluation data (the NeRO setting has none): they are loaded into ``Split.masks``
with ``eval_extras``. With ``masks_as_alpha`` (``shape.use_masks=true``) they become the
images' alpha and the photos are composited on black (``scene.background = "alpha"``).

Up axis: the mean of the cameras' up vectors (``-y`` of OpenCV), as for COLMAP.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from voxnero.data.scene import (
    Normalisation,
    Scene,
    check_camera,
    choose_normalisation,
    image_size,
    load_image_stack,
    load_masks,
    make_split,
)
from voxnero.errors import DataError

CAMERA_FILES = ("cameras_sphere.npz", "cameras.npz")
IMAGE_DIRS = ("image", "images")
MASK_DIRS = ("mask", "masks")
IMAGE_EXT = (".png", ".jpg", ".jpeg", ".PNG", ".JPG", ".JPEG")
HOLDOUT_EVERY = 8
"""Views whose index % 8 == 0 are the held-out "test" split (the DTU/NeuS convention)."""


def _first(root: Path, names: tuple[str, ...], is_dir: bool) -> Path | None:
    for n in names:
        p = root / n
        if (p.is_dir() if is_dir else p.is_file()):
            return p
    return None


def is_idr(root: Path) -> bool:
    """True if ``root`` holds a camera ``.npz`` of the layout and an image folder."""
    return (_first(root, CAMERA_FILES, False) is not None
            and _first(root, IMAGE_DIRS, True) is not None)


def _files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.suffix in IMAGE_EXT and p.is_file())


def decompose_projection(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split a 3x4 projection ``P = s K [R | t]`` into ``K`` and an OpenCV camera-to-world.

    Args:
        P: ``(3, 4)`` projection (any positive or negative overall scale).

    Returns:
        ``(K (3, 3) with K[2, 2] = 1 and positive focal lengths, c2w (4, 4))``; the camera
        centre is the null vector of ``P``.
    """
    import scipy.linalg

    P = np.asarray(P, dtype=np.float64)
    if np.linalg.det(P[:, :3]) < 0:  # overall scale negative: the same camera as -P
        P = -P
    K, R = scipy.linalg.rq(P[:, :3])
    T = np.diag(np.sign(np.diag(K)))
    K, R = K @ T, T @ R  # positive diagonal of K (T is its own inverse)
    c = -np.linalg.solve(P[:, :3], P[:, 3])
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = c
    return K / K[2, 2], c2w


def _read_cameras(path: Path, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``(world_mats (n, 4, 4), scale_mats (n, 4, 4))`` from the ``.npz``."""
    try:
        data = np.load(path)
        keys = set(data.files)
    except Exception as e:  # zip/pickle errors come in many types
        raise DataError(f"cannot read the camera file ({type(e).__name__}: {e})", path=path,
                        fix="the file must be a NumPy .npz with world_mat_<i> and scale_mat_<i>"
                        ) from None
    missing = [f"world_mat_{i}" for i in range(n) if f"world_mat_{i}" not in keys]
    if missing:
        raise DataError(f"{n} images but no {missing[0]} ({len(missing)} views without a "
                        "camera)", path=path,
                        fix="give one world_mat_<i> per image (i = index in sorted order) or "
                            "remove the extra images")
    world = np.stack([np.asarray(data[f"world_mat_{i}"], np.float64).reshape(-1, 4)[:4]
                      for i in range(n)])
    scale = np.stack([np.asarray(data[f"scale_mat_{i}"], np.float64) if f"scale_mat_{i}" in keys
                      else np.eye(4) for i in range(n)])
    if world.shape[1] == 3:
        world = np.concatenate([world, np.tile([[[0, 0, 0, 1.0]]], (n, 1, 1))], 1)
    if not (np.isfinite(world).all() and np.isfinite(scale).all()):
        raise DataError("non-finite values in world_mat/scale_mat", path=path,
                        fix="re-export the cameras")
    return world, scale


def normalisation_from_scale_mat(scale_mats: np.ndarray, path: Path) -> Normalisation:
    """The unit sphere of ``scale_mat`` as a :class:`Normalisation` (uniform scale required)."""
    S = scale_mats[0]
    if np.abs(scale_mats - S).max() > 1e-6 * max(1.0, float(np.abs(S).max())):
        raise DataError("scale_mat_i differ between views (one region of interest expected)",
                        path=path, fix="give every view the same scale_mat, or bbox=[...]")
    d = np.diag(S)[:3]
    if np.abs(d - d[0]).max() > 1e-6 * abs(d[0]) or np.abs(S[:3, :3] - np.diag(d)).max() > 1e-9:
        raise DataError(f"scale_mat is not a uniform scale + translation (diagonal {d.tolist()})",
                        path=path, fix="give a scale_mat of the form [[s,0,0,x],[0,s,0,y],"
                                       "[0,0,s,z],[0,0,0,1]], or bbox=[...]")
    return Normalisation(S[:3, 3], float(d[0]))


def _split_indices(root: Path, split: str, n: int) -> list[int]:
    sfile = root / "split.json"
    if sfile.is_file():
        try:
            ids = [int(v) for v in json.loads(sfile.read_text())[split]]
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
            raise DataError(f"split {split!r} not readable ({e!r})", path=sfile,
                            fix='split.json maps split names to view indices, e.g. '
                                '{"train": [1, 2], "test": [0]}') from None
        bad = [i for i in ids if not 0 <= i < n]
        if bad:
            raise DataError(f"split {split!r} lists view indices outside 0..{n - 1}: {bad[:5]}",
                            path=sfile, fix="list indices of existing views")
        return ids
    if split == "train":
        return [i for i in range(n) if i % HOLDOUT_EVERY != 0]
    if split == "test":
        return [i for i in range(n) if i % HOLDOUT_EVERY == 0]
    if split == "all":
        return list(range(n))
    raise DataError(f"split {split!r}: this format has train (index % {HOLDOUT_EVERY} != 0), "
                    "test (index % 8 == 0) and all", path=root,
                    fix=f'write {sfile} like {{"{split}": [0, 1]}}')


def split_names(root: Path) -> list[str]:
    """Splits a folder of this layout offers (``split.json`` keys, else train/test/all)."""
    sfile = root / "split.json"
    if sfile.is_file():
        try:
            data = json.loads(sfile.read_text())
            if isinstance(data, dict):
                return sorted(data, key=lambda s: (s != "train", s != "test", s))
        except json.JSONDecodeError:
            pass
    return ["train", "test", "all"]


def load_idr(root: str | Path, splits=("train",), white_bg: bool = False, radius=None,
             center=None, bbox=None, eval_extras: bool = False,
             masks_as_alpha: bool = False) -> Scene:
    """Load a NeuS/IDR-layout capture (see the module docstring).

    Args:
        root: the capture folder.
        splits: split names (``train``, ``test``, ``all`` or ``split.json`` keys).
        white_bg: with ``masks_as_alpha``, composite on white instead of black.
        radius, center, bbox: region of interest in the world frame (replaces ``scale_mat``).
        eval_extras: load ``mask/`` into ``Split.masks`` (evaluation only).
        masks_as_alpha: use the masks as the images' alpha (training with masks).
    """
    root = Path(root)
    cam_path = _first(root, CAMERA_FILES, False)
    img_dir = _first(root, IMAGE_DIRS, True)
    if cam_path is None or img_dir is None:
        raise DataError("not a NeuS/IDR capture (needs cameras_sphere.npz and image/)",
                        path=root, fix="point to the capture folder")
    paths = _files(img_dir)
    if not paths:
        raise DataError("no images", path=img_dir, fix="put the photos (.png/.jpg) there")
    n = len(paths)
    mask_dir = _first(root, MASK_DIRS, True)
    mask_paths = _files(mask_dir) if mask_dir is not None else []
    if mask_paths and len(mask_paths) != n:
        raise DataError(f"{len(mask_paths)} masks for {n} images", path=mask_dir,
                        fix="give one mask per image (same sorted order) or remove the folder")
    if masks_as_alpha and not mask_paths:
        raise DataError("shape.use_masks=true but the capture has no mask/ folder", path=root,
                        fix="add mask/ or drop use_masks")
    world, scale = _read_cameras(cam_path, n)
    w, h = image_size(paths[0])
    K_all, c2w_all = [], []
    for i in range(n):
        K, c2w = decompose_projection(world[i][:3])
        K[0, 2] += 0.5  # pixel centres at integers -> at i + 0.5
        K[1, 2] += 0.5
        check_camera(K, c2w, w, h, f"view {i} ({paths[i].name})", cam_path)
        K_all.append(K)
        c2w_all.append(c2w)
    K_all, c2w_all = np.stack(K_all), np.stack(c2w_all)
    if bbox is not None or radius is not None or center is not None:
        norm, rec = choose_normalisation(c2w_all, K_all, w, h, bbox=bbox, radius=radius,
                                         center=center)
    else:
        norm = normalisation_from_scale_mat(scale, cam_path)
        rec = {"method": "scale_mat: its unit sphere is the region of interest",
               **norm.to_dict()}
    out = {}
    for s in splits:
        idx = _split_indices(root, s, n)
        if not idx:
            raise DataError(f"split {s!r} is empty", path=root, fix="list some views")
        enc = load_image_stack([paths[i] for i in idx], w, h, s)[..., :3]
        masks = None
        if mask_paths and (eval_extras or masks_as_alpha):
            masks = (load_masks([mask_paths[i] for i in idx], w, h, s) > 0.5).astype(np.float32)
        if masks_as_alpha:
            enc = np.concatenate([enc, masks[..., None]], -1)
        out[s] = make_split(s, enc, K_all[idx], c2w_all[idx], norm, [paths[i].stem for i in idx],
                            white_bg, masks if eval_extras else None, None)
    up = -c2w_all[:, :3, 1].mean(0)
    up = up / max(np.linalg.norm(up), 1e-12)
    meta = {"normalisation": rec, "up_method": "mean camera up (-y) vector",
            "white_bg": bool(white_bg), "n_views": n, "camera_file": cam_path.name,
            "holdout": ("split.json" if (root / "split.json").is_file()
                        else f"views with index % {HOLDOUT_EVERY} == 0 are 'test'"),
            "masks": mask_dir.name if mask_paths else None,
            "masks_used_for_training": bool(masks_as_alpha)}
    if masks_as_alpha:
        meta["bg_color"] = (1.0, 1.0, 1.0) if white_bg else (0.0, 0.0, 0.0)
    return Scene(root=root, format="idr", splits=out, norm=norm, up=up,
                 background="alpha" if masks_as_alpha else "unknown", meta=meta)
