"""Read and write 8/16-bit PNG and JPEG images as float arrays of *encoded* values in [0, 1].

Values are whatever the file stores (normally sRGB-encoded); convert with
:mod:`voxnero.io.color`. Pillow handles 8-bit images and 16-bit grey; Pillow cannot represent
16-bit colour, so 16-bit colour (RGB, RGBA, grey+alpha) PNGs are read and written by the small
PNG codec in this module (non-interlaced, all five row filters on read).
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from voxnero.errors import DataError
from voxnero.io.color import linear_to_srgb

_PNG_SIG = b"\x89PNG\r\n\x1a\n"
_CHANNELS = {0: 1, 2: 3, 4: 2, 6: 4}  # PNG colour type -> samples per pixel


# --------------------------------------------------------------------------------------------
# reading
# --------------------------------------------------------------------------------------------

def _png_header(path: Path) -> tuple[int, int] | None:
    """(bit depth, colour type) of a PNG file, or None if the file is not a PNG."""
    with open(path, "rb") as f:
        head = f.read(33)
    if len(head) < 33 or head[:8] != _PNG_SIG or head[12:16] != b"IHDR":
        return None
    return head[24], head[25]


def _unfilter(raw: bytes, height: int, width: int, bpp: int) -> np.ndarray:
    """Undo the PNG row filters. Returns ``(height, width * bpp)`` uint8 (``bpp`` bytes/pixel)."""
    stride = width * bpp
    data = np.frombuffer(raw, dtype=np.uint8)
    if data.size != height * (stride + 1):
        raise ValueError("PNG image data has the wrong size")
    data = data.reshape(height, stride + 1)
    ftypes, rows = data[:, 0], data[:, 1:].astype(np.int32)
    out = np.zeros((height, stride), dtype=np.int32)
    prev = np.zeros(stride, dtype=np.int32)
    for y in range(height):
        r, ft = rows[y], ftypes[y]
        if ft == 0:
            cur = r
        elif ft == 1:  # Sub: running sum per byte lane
            cur = np.cumsum(r.reshape(width, bpp), axis=0).reshape(-1) & 0xFF
        elif ft == 2:  # Up
            cur = (r + prev) & 0xFF
        elif ft in (3, 4):  # Average / Paeth: sequential along the row
            cur = np.empty(stride, dtype=np.int32)
            rl, pl = r.tolist(), prev.tolist()
            cl = [0] * stride
            for i in range(stride):
                a = cl[i - bpp] if i >= bpp else 0
                b = pl[i]
                if ft == 3:
                    cl[i] = (rl[i] + ((a + b) >> 1)) & 0xFF
                else:
                    c = pl[i - bpp] if i >= bpp else 0
                    p = a + b - c
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                    pred = a if (pa <= pb and pa <= pc) else (b if pb <= pc else c)
                    cl[i] = (rl[i] + pred) & 0xFF
            cur[:] = cl
        else:
            raise ValueError(f"unknown PNG filter type {ft}")
        out[y] = cur
        prev = cur
    return out.astype(np.uint8)


def _read_png16(path: Path) -> np.ndarray:
    """Decode a non-interlaced 16-bit PNG to ``(H, W, C)`` uint16."""
    blob = path.read_bytes()
    pos, idat, ihdr = 8, [], None
    while pos + 8 <= len(blob):
        (length,) = struct.unpack(">I", blob[pos:pos + 4])
        kind = blob[pos + 4:pos + 8]
        body = blob[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat.append(body)
        elif kind == b"IEND":
            break
        pos += 12 + length
    if ihdr is None:
        raise ValueError("no IHDR chunk")
    width, height, depth, ctype, _, _, interlace = ihdr
    if depth != 16 or ctype not in _CHANNELS or interlace != 0:
        raise ValueError(f"unsupported PNG (bit depth {depth}, colour type {ctype}, "
                         f"interlace {interlace})")
    c = _CHANNELS[ctype]
    rows = _unfilter(zlib.decompress(b"".join(idat)), height, width, 2 * c)
    return rows.reshape(height, width * c, 2).view(">u2")[..., 0].reshape(height, width, c)


def _grey_alpha_to_rgba(a: np.ndarray) -> np.ndarray:
    if a.shape[2] != 2:
        return a
    return np.concatenate([a[..., :1], a[..., :1], a[..., :1], a[..., 1:]], axis=2)


def read_image(path: str | Path) -> np.ndarray:
    """Read a PNG (8 or 16 bit) or JPEG image.

    Args:
        path: image file.

    Returns:
        ``(H, W, C)`` float32 encoded values in [0, 1], ``C`` = 1 (grey), 3 (RGB) or 4 (RGBA);
        grey+alpha is expanded to RGBA and palette images to RGB/RGBA. 8-bit values are divided
        by 255, 16-bit by 65535.

    Raises:
        DataError: the file is missing or cannot be decoded.
    """
    path = Path(path)
    if not path.is_file():
        raise DataError("image file not found", path=path,
                        fix="check the file name in the scene's pose file and that the image "
                            "folder is complete")
    try:
        header = _png_header(path)
        if header is not None and header[0] == 16 and header[1] != 0:
            return _grey_alpha_to_rgba(_read_png16(path).astype(np.float32) / 65535.0)
        with Image.open(path) as im:
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I;16L"):
                return (np.asarray(im, dtype=np.uint16).astype(np.float32) / 65535.0)[..., None]
            if mode == "P":
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
            elif mode in ("1", "CMYK", "YCbCr", "I", "F", "PA"):
                im = im.convert("RGB" if mode != "PA" else "RGBA")
            arr = np.asarray(im)
    except (OSError, ValueError, UnidentifiedImageError, zlib.error, struct.error) as e:
        raise DataError(f"cannot read image ({e})", path=path,
                        fix="re-export the image as an 8- or 16-bit PNG or a JPEG") from None
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.dtype != np.uint8:
        raise DataError(f"unsupported image sample type {arr.dtype}", path=path,
                        fix="re-export the image as an 8- or 16-bit PNG or a JPEG")
    return _grey_alpha_to_rgba(arr.astype(np.float32) / 255.0)


# --------------------------------------------------------------------------------------------
# writing
# --------------------------------------------------------------------------------------------

def _chunk(kind: bytes, body: bytes) -> bytes:
    return (struct.pack(">I", len(body)) + kind + body
            + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))


def _write_png16(path: Path, q: np.ndarray) -> None:
    """Write ``(H, W, C)`` uint16 as a 16-bit PNG (filter 0, zlib level 6)."""
    h, w, c = q.shape
    ctype = {1: 0, 2: 4, 3: 2, 4: 6}[c]
    rows = q.astype(">u2").reshape(h, w * c).view(np.uint8)
    raw = np.concatenate([np.zeros((h, 1), np.uint8), rows], axis=1).tobytes()
    ihdr = struct.pack(">IIBBBBB", w, h, 16, ctype, 0, 0, 0)
    path.write_bytes(_PNG_SIG + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(raw, 6))
                     + _chunk(b"IEND", b""))


def write_png(path: str | Path, img: np.ndarray, bits: int = 8) -> None:
    """Write an image of encoded values in [0, 1] as an 8- or 16-bit PNG.

    Args:
        path: output file (parent folders are created).
        img: ``(H, W)`` or ``(H, W, C)`` float, ``C`` in {1, 2, 3, 4}; clipped to [0, 1] and
            quantised with ``round(v * (2**bits - 1))``. A torch tensor is accepted.
        bits: 8 or 16.
    """
    if bits not in (8, 16):
        raise ValueError("bits must be 8 or 16")
    if hasattr(img, "detach"):
        img = img.detach().cpu().numpy()
    img = np.asarray(img, dtype=np.float64)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[2] not in (1, 2, 3, 4):
        raise ValueError(f"expected (H, W[, C]) with C in 1..4, got {img.shape}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    q = np.rint(np.clip(np.nan_to_num(img), 0.0, 1.0) * (2**bits - 1))
    if bits == 8:
        q = q.astype(np.uint8)
        Image.fromarray(q[..., 0] if q.shape[2] == 1 else q).save(path, format="PNG")
    elif q.shape[2] == 1:
        Image.fromarray(q[..., 0].astype(np.uint16)).save(path, format="PNG")
    else:
        _write_png16(path, q.astype(np.uint16))


def save_linear_png(path: str | Path, linear: np.ndarray, bits: int = 8) -> None:
    """Clip linear radiance to [0, 1], sRGB-encode it and write a PNG (for previews).

    Args:
        path: output file.
        linear: ``(H, W[, C])`` linear values (numpy or torch).
        bits: 8 or 16.
    """
    if hasattr(linear, "detach"):
        linear = linear.detach().cpu().numpy()
    write_png(path, linear_to_srgb(np.asarray(linear, dtype=np.float32)), bits=bits)
