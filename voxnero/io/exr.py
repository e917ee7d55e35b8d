"""OpenEXR read/write (through the ``OpenEXR`` package) and a small Radiance ``.hdr`` reader.

All values are linear HDR (radiance, depth, normals ...), never sRGB-encoded. Arrays are
``(H, W, C)`` float32 with row 0 at the top of the image.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import OpenEXR

from voxnero.errors import DataError

_FIX_EXR = "re-export the file as a scanline OpenEXR with finite values (R, G, B[, A] or Y)"


def _order(names: list[str]) -> list[str]:
    """Channel names in a useful order: R, G, B, A / Y first, then the rest alphabetically."""
    rank = {"R": 0, "G": 1, "B": 2, "A": 3, "Y": 0}

    def key(n: str) -> tuple[int, str]:
        return (rank.get(n.split(".")[-1], 9), n)

    return sorted(names, key=key)


def read_exr(path: str | Path) -> np.ndarray:
    """Read an OpenEXR image.

    Args:
        path: ``.exr`` file (first part of a multi-part file).

    Returns:
        ``(H, W, C)`` float32: RGB(A) files give C = 3 (4), a single channel (e.g. ``Y`` or
        ``Z``) gives C = 1; other channel sets are returned in R, G, B, A order, then by name.

    Raises:
        DataError: missing or unreadable file, or NaN/Inf values.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError("EXR file not found", path=path, fix="check the path")
    try:
        with OpenEXR.File(str(path), separate_channels=True) as f:
            chans = f.channels()
            arrays = {name: np.asarray(ch.pixels) for name, ch in chans.items()}
    except Exception as e:  # the binding raises plain RuntimeError/ValueError
        raise DataError(f"cannot read EXR ({e})", path=path, fix=_FIX_EXR) from None
    if not arrays:
        raise DataError("EXR file has no channels", path=path, fix=_FIX_EXR)
    names = _order(list(arrays))
    shapes = {arrays[n].shape for n in names}
    if len(shapes) != 1:
        raise DataError(f"EXR channels have different sizes {sorted(shapes)} (subsampled?)",
                        path=path, fix=_FIX_EXR)
    img = np.stack([arrays[n].astype(np.float32) for n in names], axis=-1)
    bad = ~np.isfinite(img)
    if bad.any():
        idx = np.argwhere(bad)[0]
        raise DataError(f"EXR contains {int(bad.sum())} NaN/Inf value(s), first at "
                        f"row {idx[0]}, column {idx[1]}", path=path,
                        fix="re-render or repair the file (e.g. replace NaN/Inf by 0)")
    return img


def write_exr(path: str | Path, img: np.ndarray, half: bool = True) -> None:
    """Write an OpenEXR image (scanline, ZIP compression).

    Args:
        path: output file (parent folders are created).
        img: ``(H, W)`` or ``(H, W, C)`` with C = 1 (written as channel ``Y``), 3 (``R, G, B``)
            or 4 (``R, G, B, A``); numpy or torch, linear values.
        half: store 16-bit half floats (default) instead of 32-bit floats.
    """
    if hasattr(img, "detach"):
        img = img.detach().cpu().numpy()
    img = np.asarray(img)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 3, 4):
        raise ValueError(f"write_exr expects (H, W[, C]) with C in 1, 3, 4; got {img.shape}")
    dtype = np.float16 if half else np.float32
    names = {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}[img.shape[2]]
    channels = {n: np.ascontiguousarray(img[..., i].astype(dtype)) for i, n in enumerate(names)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with OpenEXR.File(header, channels) as f:
        f.write(str(path))


def read_hdr(path: str | Path) -> np.ndarray:
    """Read a Radiance RGBE (``.hdr`` / ``.pic``) image.

    Supports the ``32-bit_rle_rgbe`` format with ``-Y H +X W`` orientation (what every common
    tool writes), both flat and new-style run-length-encoded scanlines. ``EXPOSURE`` lines are
    ignored (values are returned as stored).

    Args:
        path: ``.hdr`` file.

    Returns:
        ``(H, W, 3)`` float32 linear RGB, row 0 at the top.

    Raises:
        DataError: missing, truncated or unsupported file.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError("HDR file not found", path=path, fix="check the path")
    fix = "convert the file to OpenEXR (.exr) or a standard -Y H +X W RGBE .hdr"
    data = path.read_bytes()
    if not (data.startswith(b"#?RADIANCE") or data.startswith(b"#?RGBE")):
        raise DataError("not a Radiance .hdr file (missing '#?RADIANCE' header)", path=path,
                        fix=fix)
    pos = 0
    fmt = None
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise DataError("truncated .hdr header", path=path, fix=fix)
        line = data[pos:end].strip()
        pos = end + 1
        if line.startswith(b"FORMAT="):
            fmt = line[7:].decode("ascii", "replace")
        if line == b"":
            break
    if fmt not in (None, "32-bit_rle_rgbe"):
        raise DataError(f"unsupported .hdr FORMAT {fmt!r}", path=path, fix=fix)
    end = data.find(b"\n", pos)
    res = data[pos:end].decode("ascii", "replace").strip()
    pos = end + 1
    m = re.fullmatch(r"-Y\s+(\d+)\s+\+X\s+(\d+)", res)
    if not m:
        raise DataError(f"unsupported .hdr orientation {res!r}", path=path, fix=fix)
    h, w = int(m.group(1)), int(m.group(2))
    buf = np.frombuffer(data, dtype=np.uint8, offset=pos)
    try:
        rgbe = _decode_rgbe(buf, h, w)
    except (IndexError, ValueError) as e:
        raise DataError(f"corrupt or truncated .hdr pixel data ({e})", path=path,
                        fix=fix) from None
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(1.0, e - 136), 0.0).astype(np.float32)
    return rgbe[..., :3].astype(np.float32) * scale[..., None]


def _decode_rgbe(buf: np.ndarray, h: int, w: int) -> np.ndarray:
    """Decode RGBE scanlines (flat or new-style RLE) to ``(h, w, 4)`` uint8."""
    out = np.empty((h, w, 4), dtype=np.uint8)
    pos = 0
    for y in range(h):
        hdr = buf[pos:pos + 4]
        rle = (8 <= w < 32768 and len(hdr) == 4 and hdr[0] == 2 and hdr[1] == 2
               and not (hdr[2] & 0x80) and (int(hdr[2]) << 8 | int(hdr[3])) == w)
        if not rle:  # flat scanline (old-style RLE is not supported)
            row = buf[pos:pos + 4 * w]
            if row.size != 4 * w:
                raise ValueError(f"scanline {y} is short")
            out[y] = row.reshape(w, 4)
            pos += 4 * w
            continue
        pos += 4
        for c in range(4):
            x = 0
            lane = out[y, :, c]
            while x < w:
                n = int(buf[pos])
                pos += 1
                if n > 128:
                    n -= 128
                    if x + n > w:
                        raise ValueError(f"run overflows scanline {y}")
                    lane[x:x + n] = buf[pos]
                    pos += 1
                else:
                    if n == 0 or x + n > w:
                        raise ValueError(f"bad literal count in scanline {y}")
                    chunk = buf[pos:pos + n]
                    if chunk.size != n:
                        raise ValueError(f"scanline {y} is short")
                    lane[x:x + n] = chunk
                    pos += n
                x += n
    return out


def read_envmap(path: str | Path) -> np.ndarray:
    """Read an equirectangular environment map (``.exr`` or ``.hdr``) as ``(H, W, 3)`` linear RGB.

    An alpha channel is dropped; a single-channel map is replicated to RGB.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".exr":
        img = read_exr(path)
    elif suffix in (".hdr", ".pic", ".rgbe"):
        img = read_hdr(path)
    else:
        raise DataError(f"unknown environment map type {suffix!r}", path=path,
                        fix="give an equirectangular .exr or .hdr file")
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    return np.ascontiguousarray(img[..., :3])
