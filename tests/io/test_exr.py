"""EXR round trips (half/float, 1/3/4 channels), NaN/Inf refusal, Radiance .hdr reading."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from voxnero.errors import DataError
from voxnero.io.exr import read_envmap, read_exr, read_hdr, write_exr

DEV = Path(__file__).resolve().parents[2].parent / "shared" / "data"


@pytest.mark.parametrize("channels", [1, 3, 4])
@pytest.mark.parametrize("half", [True, False])
def test_exr_round_trip(tmp_path, channels, half):
    rng = np.random.default_rng(channels)
    img = (rng.random((6, 9, channels)) * 100).astype(np.float32)
    write_exr(tmp_path / "a.exr", img, half=half)
    out = read_exr(tmp_path / "a.exr")
    assert out.shape == img.shape and out.dtype == np.float32
    if half:  # half float: 11-bit significand, relative error <= 2^-11
        np.testing.assert_allclose(out, img, rtol=2.0**-11)
        np.testing.assert_array_equal(out, img.astype(np.float16).astype(np.float32))
    else:
        np.testing.assert_array_equal(out, img)


def test_exr_channel_names_and_storage(tmp_path):
    write_exr(tmp_path / "rgba.exr", np.zeros((2, 3, 4)), half=True)
    with OpenEXR.File(str(tmp_path / "rgba.exr"), separate_channels=True) as f:
        ch = f.channels()
        assert sorted(ch) == ["A", "B", "G", "R"]
        assert ch["R"].pixels.dtype == np.float16
    write_exr(tmp_path / "y.exr", np.zeros((2, 3)), half=False)
    with OpenEXR.File(str(tmp_path / "y.exr"), separate_channels=True) as f:
        assert list(f.channels()) == ["Y"] and f.channels()["Y"].pixels.dtype == np.float32


def test_exr_rows_and_channel_order(tmp_path):
    """Row 0 is the top and R, G, B keep their order (written by the OpenEXR API directly)."""
    h, w = 4, 5
    r = np.arange(h * w, dtype=np.float32).reshape(h, w)
    chans = {"B": r + 2000, "G": r + 1000, "R": r}
    hdr = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(hdr, chans) as f:
        f.write(str(tmp_path / "o.exr"))
    out = read_exr(tmp_path / "o.exr")
    np.testing.assert_array_equal(out[..., 0], r)
    np.testing.assert_array_equal(out[..., 2], r + 2000)
    assert out[0, 1, 0] == 1.0 and out[1, 0, 0] == w


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_exr_non_finite_is_refused(tmp_path, bad):
    img = np.ones((3, 4, 3), np.float32)
    img[2, 1, 0] = bad
    write_exr(tmp_path / "n.exr", img, half=False)
    with pytest.raises(DataError, match=r"NaN/Inf.*row 2, column 1") as e:
        read_exr(tmp_path / "n.exr")
    assert "n.exr" in str(e.value) and "fix:" in str(e.value)


def test_exr_missing_and_garbage(tmp_path):
    with pytest.raises(DataError, match="not found"):
        read_exr(tmp_path / "none.exr")
    (tmp_path / "g.exr").write_bytes(b"\x76\x2f\x31\x01garbage")
    with pytest.raises(DataError, match="cannot read EXR"):
        read_exr(tmp_path / "g.exr")


# --------------------------------------------------------------------------------------------
# Radiance .hdr: a tiny RGBE writer (flat or new-style RLE scanlines), written from the spec
# --------------------------------------------------------------------------------------------

def _to_rgbe(img: np.ndarray) -> np.ndarray:
    m = img.max(-1)
    mant, exp = np.frexp(m)  # m = mant * 2^exp, mant in [0.5, 1)
    scale = np.where(m > 1e-32, mant * 256.0 / np.maximum(m, 1e-32), 0.0)
    rgbe = np.zeros(img.shape[:2] + (4,), np.uint8)
    rgbe[..., :3] = np.floor(img * scale[..., None]).clip(0, 255)
    rgbe[..., 3] = np.where(m > 1e-32, exp + 128, 0)
    return rgbe


def _rle_lane(lane: np.ndarray) -> bytes:
    out, i, n = bytearray(), 0, len(lane)
    while i < n:
        j = i
        while j < n and lane[j] == lane[i] and j - i < 127:
            j += 1
        if j - i >= 3:
            out += bytes([128 + j - i, int(lane[i])])
            i = j
            continue
        j = i
        while j < n and j - i < 128 and not (j + 2 < n and lane[j] == lane[j + 1] == lane[j + 2]):
            j += 1
        out += bytes([j - i]) + bytes(lane[i:j].tolist())
        i = j
    return bytes(out)


def write_hdr(path: Path, img: np.ndarray, rle: bool) -> None:
    h, w, _ = img.shape
    rgbe = _to_rgbe(img)
    body = bytearray()
    for y in range(h):
        if rle:
            body += bytes([2, 2, w >> 8, w & 255])
            for c in range(4):
                body += _rle_lane(rgbe[y, :, c])
        else:
            body += rgbe[y].tobytes()
    head = f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n\n-Y {h} +X {w}\n".encode()
    path.write_bytes(head + bytes(body))


@pytest.mark.parametrize("rle", [False, True])
def test_hdr_read(tmp_path, rle):
    rng = np.random.default_rng(int(rle))
    h, w = 6, 40  # RLE needs 8 <= width < 32768
    img = (rng.random((h, w, 3)) ** 3 * 50).astype(np.float32)
    img[2, 5:30] = [3.0, 0.5, 0.25]  # long runs
    img[4, :] = 0.0
    write_hdr(tmp_path / "a.hdr", img, rle)
    out = read_hdr(tmp_path / "a.hdr")
    assert out.shape == (h, w, 3) and out.dtype == np.float32
    # RGBE keeps 8 bits of mantissa for the largest channel: error <= max channel / 128
    err = np.abs(out - img).max(-1)
    assert np.all(err <= img.max(-1) / 128 + 1e-30)
    assert np.all(out[4] == 0)
    np.testing.assert_allclose(out[2, 10], [3.0, 0.5, 0.25], rtol=1e-6)


def test_hdr_errors(tmp_path):
    (tmp_path / "x.hdr").write_bytes(b"P6\n1 1\n255\n\x00\x00\x00")
    with pytest.raises(DataError, match="not a Radiance"):
        read_hdr(tmp_path / "x.hdr")
    write_hdr(tmp_path / "t.hdr", np.ones((4, 16, 3), np.float32), rle=True)
    blob = (tmp_path / "t.hdr").read_bytes()
    (tmp_path / "t.hdr").write_bytes(blob[:-10])
    with pytest.raises(DataError, match="truncated"):
        read_hdr(tmp_path / "t.hdr")


def test_read_envmap_dispatch(tmp_path):
    img = np.full((4, 8, 3), 2.0, np.float32)
    write_exr(tmp_path / "e.exr", np.dstack([img, np.ones((4, 8))]), half=False)
    write_hdr(tmp_path / "e.hdr", img, rle=True)
    np.testing.assert_array_equal(read_envmap(tmp_path / "e.exr"), img)
    np.testing.assert_allclose(read_envmap(tmp_path / "e.hdr"), img, rtol=1 / 128)
    with pytest.raises(DataError, match="unknown environment map type"):
        read_envmap(tmp_path / "e.png")


def test_dev_envmap_reads():
    path = DEV / "sphere_gold" / "gt" / "envmap.exr"
    if not path.is_file():
        pytest.skip(f"dev scenes not found at {DEV}")
    env = read_envmap(path)
    assert env.shape == (256, 512, 3) and env.min() >= 0 and env.max() > 1
