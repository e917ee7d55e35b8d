"""PNG/JPEG I/O: 8/16-bit round trips, every PNG row filter, cross-checks with Pillow, errors."""

from __future__ import annotations

import struct
import zlib

import numpy as np
import pytest
from PIL import Image

from voxnero.errors import DataError
from voxnero.io.color import linear_to_srgb
from voxnero.io.images import read_image, save_linear_png, write_png


@pytest.mark.parametrize("channels", [1, 3, 4])
@pytest.mark.parametrize("bits", [8, 16])
def test_png_round_trip(tmp_path, channels, bits):
    rng = np.random.default_rng(channels + bits)
    img = rng.random((7, 11, channels))
    path = tmp_path / "x.png"
    write_png(path, img, bits=bits)
    out = read_image(path)
    assert out.shape == (7, 11, channels) and out.dtype == np.float32
    q = 2**bits - 1
    # quantisation: at most half a level (plus float32 rounding)
    np.testing.assert_allclose(out, img, atol=0.5 / q + 1e-7)
    # and exactly the rounded level
    np.testing.assert_array_equal(np.rint(out.astype(np.float64) * q), np.rint(img * q))


def test_png_2d_input_and_clipping(tmp_path):
    img = np.array([[-0.5, 0.0, 0.25], [1.0, 1.5, np.nan]])
    write_png(tmp_path / "g.png", img)
    out = read_image(tmp_path / "g.png")[..., 0]
    np.testing.assert_allclose(out, [[0, 0, 64 / 255], [1, 1, 0]], atol=1e-7)


@pytest.mark.parametrize("channels", [3, 4])
def test_png16_written_file_is_standard(tmp_path, channels):
    """Pillow decodes 16-bit colour PNGs to their high bytes: an independent decoder."""
    rng = np.random.default_rng(1)
    img = rng.random((5, 6, channels))
    write_png(tmp_path / "c.png", img, bits=16)
    q = np.rint(img * 65535).astype(np.uint16)
    with Image.open(tmp_path / "c.png") as im:
        np.testing.assert_array_equal(np.asarray(im), (q >> 8).astype(np.uint8))


def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def _filter_row(ft, row, prev, bpp):
    """PNG encoder-side filter of one row (bytes as ints), written from the spec."""
    out = []
    for i, x in enumerate(row):
        a = row[i - bpp] if i >= bpp else 0
        b = prev[i]
        c = prev[i - bpp] if i >= bpp else 0
        pred = [0, a, b, (a + b) // 2, _paeth(a, b, c)][ft]
        out.append((x - pred) % 256)
    return out


def _png16_with_filters(path, q, filters):
    h, w, c = q.shape
    rows = q.astype(">u2").reshape(h, w * c).view(np.uint8)
    raw, prev = bytearray(), [0] * rows.shape[1]
    for y in range(h):
        row = rows[y].tolist()
        ft = filters[y % len(filters)]
        raw += bytes([ft] + _filter_row(ft, row, prev, 2 * c))
        prev = row

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(
            ">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    ctype = {2: 4, 3: 2, 4: 6}[c]
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16,
                                                                       ctype, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(bytes(raw))) + chunk(b"IEND", b""))


@pytest.mark.parametrize("channels", [2, 3, 4])
def test_png16_reader_undoes_every_filter(tmp_path, channels):
    rng = np.random.default_rng(channels)
    q = rng.integers(0, 65536, size=(10, 9, channels), dtype=np.uint16)
    q[3] = q[2]  # repeated rows and flat runs exercise Up/Paeth ties
    q[5, :4] = 1000
    path = tmp_path / "f.png"
    _png16_with_filters(path, q, filters=[0, 1, 2, 3, 4])
    out = read_image(path)
    expect = q.astype(np.float32) / 65535
    if channels == 2:  # grey + alpha is returned as RGBA
        expect = np.concatenate([expect[..., :1]] * 3 + [expect[..., 1:]], axis=-1)
    np.testing.assert_array_equal(out, expect)


def test_grey_alpha_8bit_is_rgba(tmp_path):
    la = np.dstack([np.full((3, 4), 100, np.uint8), np.full((3, 4), 50, np.uint8)])
    Image.fromarray(la, mode="LA").save(tmp_path / "la.png")
    out = read_image(tmp_path / "la.png")
    assert out.shape == (3, 4, 4)
    np.testing.assert_allclose(out[0, 0], [100 / 255] * 3 + [50 / 255], atol=1e-7)


def test_palette_png_is_rgb(tmp_path):
    img = Image.fromarray(np.array([[[255, 0, 0], [0, 0, 255]]], np.uint8)).convert("P")
    img.save(tmp_path / "p.png")
    out = read_image(tmp_path / "p.png")
    np.testing.assert_allclose(out[0], [[1, 0, 0], [0, 0, 1]], atol=1e-7)


def test_jpeg_read(tmp_path):
    # a smooth image survives JPEG at quality 95 to a few levels
    y, x = np.mgrid[0:32, 0:32] / 31.0
    img = np.stack([x, y, 0.5 * np.ones_like(x)], -1)
    Image.fromarray(np.rint(img * 255).astype(np.uint8)).save(tmp_path / "a.jpg", quality=95)
    out = read_image(tmp_path / "a.jpg")
    assert out.shape == (32, 32, 3)
    assert np.abs(out - img).max() < 6 / 255


def test_save_linear_png_encodes_srgb(tmp_path):
    lin = np.array([[[0.0, 0.21586050, 0.5], [1.0, 2.0, -1.0]]])
    save_linear_png(tmp_path / "l.png", lin)
    out = read_image(tmp_path / "l.png")
    np.testing.assert_allclose(out, np.rint(linear_to_srgb(np.clip(lin, 0, 1)) * 255) / 255,
                               atol=1e-7)
    assert out[0, 0, 1] == pytest.approx(128 / 255, abs=1e-7)  # srgb_to_linear(128/255) = 0.2158605


def test_missing_and_unreadable(tmp_path):
    with pytest.raises(DataError, match="not found") as e:
        read_image(tmp_path / "nope.png")
    assert "nope.png" in str(e.value)
    (tmp_path / "bad.png").write_bytes(b"this is not an image")
    with pytest.raises(DataError, match="cannot read image") as e:
        read_image(tmp_path / "bad.png")
    assert "bad.png" in str(e.value) and "fix:" in str(e.value)
    # a truncated 16-bit PNG
    write_png(tmp_path / "t.png", np.ones((8, 8, 3)), bits=16)
    blob = (tmp_path / "t.png").read_bytes()
    (tmp_path / "t.png").write_bytes(blob[: len(blob) // 2])
    with pytest.raises(DataError, match="cannot read image"):
        read_image(tmp_path / "t.png")
