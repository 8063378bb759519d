"""relight.io's PNG codec: the zlib + NumPy path for the common PNG (8/16-bit grey, grey + alpha, RGB, RGBA, rows
filtered None, Sub or Up) against pypng, the independent pure-Python codec that reads everything else."""

import struct
import zlib

import numpy as np
import png
import pytest

from relight.io import read_png, write_png


def _pypng(path) -> np.ndarray:
    w, h, rows, info = png.Reader(bytes=path.read_bytes()).asDirect()
    return np.vstack([np.asarray(r)[None] for r in rows]).reshape(h, w, info["planes"])


def _paeth(a, b, c):
    p = a + b - c
    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
    return a if pa <= pb and pa <= pc else (b if pb <= pc else c)


def _filtered_png(img: np.ndarray, kinds) -> bytes:
    """``img`` as PNG bytes with row y filtered by ``kinds[y]`` (0-4), by the specification's definitions
    (PNG 9.2) written out byte by byte: a reference independent of the codec under test."""
    h, w, c = img.shape
    depth = 16 if img.dtype == np.uint16 else 8
    raw = np.frombuffer(np.ascontiguousarray(img, ">u2" if depth == 16 else np.uint8).tobytes(),
                        np.uint8).reshape(h, -1).astype(int)
    bpp = c * depth // 8
    out = bytearray()
    for y in range(h):
        out.append(kinds[y])
        for x in range(raw.shape[1]):
            a = raw[y, x - bpp] if x >= bpp else 0
            b = raw[y - 1, x] if y else 0
            cc = raw[y - 1, x - bpp] if y and x >= bpp else 0
            pred = (0, a, b, (a + b) // 2, _paeth(a, b, cc))[kinds[y]]
            out.append((raw[y, x] - pred) % 256)

    def chunk(kind, payload):
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", zlib.crc32(kind + payload))

    ihdr = struct.pack(">IIBBBBB", w, h, depth, {1: 0, 2: 4, 3: 2, 4: 6}[c], 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(bytes(out)))
            + chunk(b"IEND", b""))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("channels", [1, 2, 3, 4])
def test_round_trip_and_pypng_reads_what_is_written(tmp_path, dtype, channels):
    rng = np.random.default_rng(channels)
    img = rng.integers(0, np.iinfo(dtype).max, (13, 17, channels), endpoint=True).astype(dtype)
    write_png(tmp_path / "a.png", img)
    np.testing.assert_array_equal(read_png(tmp_path / "a.png"), img)
    np.testing.assert_array_equal(_pypng(tmp_path / "a.png"), img)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_every_row_filter_decodes_to_the_image(tmp_path, dtype):
    """Rows filtered None, Sub, Up (the NumPy path, mixed row by row) and, in a second file, Average and Paeth
    (handed to pypng): the image back exactly either way."""
    rng = np.random.default_rng(7)
    img = rng.integers(0, np.iinfo(dtype).max, (10, 9, 3), endpoint=True).astype(dtype)
    for name, kinds in (("fast", [0, 1, 2, 2, 1, 0, 2, 1, 1, 2]), ("pypng", [3, 4, 0, 1, 2, 4, 3, 2, 1, 0])):
        (tmp_path / f"{name}.png").write_bytes(_filtered_png(img, kinds))
        np.testing.assert_array_equal(read_png(tmp_path / f"{name}.png"), img, err_msg=name)
        np.testing.assert_array_equal(_pypng(tmp_path / f"{name}.png"), img, err_msg=name)
