"""8- and 16-bit PNG. Pillow reduces 16-bit PNGs to 8 bits, which would throw away the low byte of every DiLiGenT
capture, so it is not used here. The common case (8- or 16-bit grey, grey + alpha, RGB or RGBA, not interlaced,
rows filtered None, Sub or Up: what :func:`write_png` writes) is decoded with zlib and NumPy, at the inflate's
speed: a delivery's 16-bit photographs are read tens of times faster than by pypng, a pure-Python decoder,
which reads every other PNG (palettes, bit depths below 8, Adam7, the Average and Paeth filters) and tells
what is wrong with a corrupt file. The writer filters every row Up (the difference from the row above) and
deflates it with zlib."""

from __future__ import annotations

import os
import zlib
from pathlib import Path

import numpy as np
import png

from ..results import atomic_write_bytes
from ._errors import ImageFormatError, check_image_size, existing_file

__all__ = ["read_png", "write_png"]


def read_png(path: str | os.PathLike, shape: tuple[int, int] | None = None,
             max_pixels: int | None = None) -> np.ndarray:
    """Read a PNG as ``[H, W, C]`` uint8 (bit depth <= 8) or uint16 (bit depth 16),
    values as stored (no gamma decoding). Palettes are expanded to RGB(A); bit
    depths 1, 2 and 4 are rescaled to the 0..255 range. Raises
    ``ImageFormatError`` naming the file when it is not a readable PNG (bad
    signature, CRC, zlib stream, truncation) or declares more than
    ``MAX_IMAGE_PIXELS`` (checked before any row is decoded). ``shape``: the
    ``(H, W)`` the caller needs (a camera's mask or photograph) and
    ``max_pixels``: a smaller bound of its own (a label map), both compared
    with the header before any row is decoded, so a small file declaring
    16384^2 pixels costs nothing."""
    path = Path(path)
    existing_file(path, "PNG file")
    # From memory, not the file: pypng reads each chunk with one read(length), and a file object allocates
    # the declared length (up to 2^31 bytes in a corrupt file) before finding the file shorter.
    data = path.read_bytes()
    try:
        fast = _decode(data, path, shape, max_pixels)
        if fast is not None:
            return fast
        w, h, rows, info = png.Reader(bytes=data).asDirect()
        # The header's size, before any row is decoded (a corrupt IHDR declares up to 2^31 x 2^31).
        _check_header(path, h, w, info["planes"], shape, max_pixels)
        dtype = np.uint16 if info["bitdepth"] > 8 else np.uint8
        arr = np.vstack([np.asarray(r, dtype=dtype)[None] for r in rows])
    except (ImageFormatError, MemoryError):
        raise
    # pypng is a pure-Python decoder: a corrupt file surfaces as its own errors, zlib.error, or whatever a
    # mangled chunk makes its parsing code raise; all of them mean the same thing here.
    except Exception as err:
        raise ImageFormatError(f"{path}: corrupt or truncated PNG ({type(err).__name__}: {err})") from err
    planes = info["planes"]
    if arr.shape != (h, w * planes):
        raise ImageFormatError(f"{path}: PNG pixel data has shape {arr.shape}, expected {(h, w * planes)}")
    arr = arr.reshape(h, w, planes)
    depth = info["bitdepth"]
    if depth < 8:
        arr = (arr.astype(np.uint16) * 255 // (2**depth - 1)).astype(np.uint8)
    return arr


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write a uint8 or uint16 ``[H, W]`` or ``[H, W, C]`` (C = 1..4: grey, grey+alpha,
    RGB, RGBA) image as an 8- or 16-bit PNG, atomically. Float images must be
    converted first (:func:`relight.tonemap.to_uint8` / ``to_uint16``)."""
    path = Path(path)
    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"{path}: PNG needs a uint8 or uint16 image, got {img.dtype} (use to_uint8/to_uint16)")
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or not 1 <= img.shape[-1] <= 4 or img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"{path}: PNG image must be [H, W] or [H, W, 1..4], got shape {img.shape}")
    atomic_write_bytes(path, lambda fh: fh.write(_encode(img)))


_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# PNG colour type -> samples per pixel, for the types decoded here (0 grey, 2 RGB, 4 grey + alpha, 6 RGBA).
_PLANES = {0: 1, 2: 3, 4: 2, 6: 4}
_COLOUR = {1: 0, 2: 4, 3: 2, 4: 6}


def _chunk(kind: bytes, payload: bytes) -> bytes:
    return len(payload).to_bytes(4, "big") + kind + payload + zlib.crc32(kind + payload).to_bytes(4, "big")


def _encode(img: np.ndarray) -> bytes:
    """``img`` [H, W, C] uint8 / uint16 as PNG bytes: every row filtered Up, deflated at zlib's level 6."""
    h, w, c = img.shape
    depth = 16 if img.dtype == np.uint16 else 8
    rows = np.frombuffer(np.ascontiguousarray(img, ">u2" if depth == 16 else np.uint8).tobytes(),
                         np.uint8).reshape(h, -1)
    filtered = np.empty((h, rows.shape[1] + 1), np.uint8)
    filtered[:, 0] = 2  # Up
    filtered[0, 1:] = rows[0]
    np.subtract(rows[1:], rows[:-1], out=filtered[1:, 1:])  # modulo 256
    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([depth, _COLOUR[c], 0, 0, 0])
    return (_SIGNATURE + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(filtered.tobytes(), 6))
            + _chunk(b"IEND", b""))


def _check_header(path: Path, h: int, w: int, planes: int, shape, max_pixels) -> None:
    """The header's size against the limits, before any row is decoded (a corrupt IHDR declares up to
    2^31 x 2^31): ``MAX_IMAGE_PIXELS``, the ``shape`` the caller needs and its own ``max_pixels``."""
    check_image_size(path, h, w, planes, "the PNG header")
    if shape is not None and (h, w) != tuple(shape):
        raise ImageFormatError(f"{path}: the PNG header says {w}x{h} pixels, expected {shape[1]}x{shape[0]}")
    if max_pixels is not None and h * w > max_pixels:
        raise ImageFormatError(f"{path}: the PNG header says {w}x{h} pixels, more than the {max_pixels} "
                               "this file may have")


def _chunks(data: bytes) -> tuple[bytes, bytes] | None:
    """(IHDR's payload, the IDAT payloads joined) of PNG ``data`` with every chunk's CRC right, else None."""
    if data[:8] != _SIGNATURE:
        return None
    i, ihdr, idat = 8, None, []
    while i + 12 <= len(data):
        n = int.from_bytes(data[i:i + 4], "big")
        end = i + 12 + n
        kind = data[i + 4:i + 8]
        if end > len(data) or zlib.crc32(data[i + 4:i + 8 + n]) != int.from_bytes(data[end - 4:end], "big"):
            return None
        if kind == b"IHDR":
            ihdr = data[i + 8:i + 8 + n]
        elif kind == b"IDAT":
            idat.append(data[i + 8:i + 8 + n])
        elif kind == b"IEND":
            break
        i = end
    return None if ihdr is None or len(ihdr) != 13 or not idat else (ihdr, b"".join(idat))


def _unfilter(kinds: np.ndarray, filtered: np.ndarray, bpp: int) -> np.ndarray:
    """The bytes [H, stride] of rows filtered None (0), Sub (1) or Up (2) (PNG specification, 9.2), modulo 256."""
    if np.all(kinds == 2):  # Up everywhere (this module's writer): one running sum down the columns
        return np.cumsum(filtered, axis=0, dtype=np.uint8)
    h, stride = filtered.shape
    out = np.empty((h, stride), np.uint8)
    prev = np.zeros(stride, np.uint8)
    for y in range(h):
        if kinds[y] == 0:
            out[y] = filtered[y]
        elif kinds[y] == 1:  # Sub: a running sum along the row, per byte of the pixel
            out[y] = np.cumsum(filtered[y].reshape(-1, bpp), axis=0, dtype=np.uint8).reshape(stride)
        else:
            np.add(filtered[y], prev, out=out[y])
        prev = out[y]
    return out


def _decode(data: bytes, path: Path, shape, max_pixels) -> np.ndarray | None:
    """The PNG ``data`` decoded with zlib and NumPy, or None where pypng is to read it: a colour type, depth,
    interlace or row filter not handled here, or anything malformed (pypng then names the problem). The size
    checks (:func:`_check_header`) come before anything is inflated, and no more than the header's size is."""
    parts = _chunks(data)
    if parts is None:
        return None
    ihdr, idat = parts
    w, h = int.from_bytes(ihdr[:4], "big"), int.from_bytes(ihdr[4:8], "big")
    depth, colour, method, filtering, interlace = ihdr[8:13]
    planes = _PLANES.get(colour)
    if planes is None or depth not in (8, 16) or method or filtering or interlace or not w or not h:
        return None
    _check_header(path, h, w, planes, shape, max_pixels)
    bpp = planes * depth // 8
    stride = w * bpp
    try:
        raw = zlib.decompressobj().decompress(idat, h * (stride + 1) + 1)
    except zlib.error:
        return None
    if len(raw) != h * (stride + 1):
        return None
    rows = np.frombuffer(raw, np.uint8).reshape(h, stride + 1)
    if rows[:, 0].max() > 2:  # Average or Paeth: each byte depends on its reconstructed left neighbour
        return None
    out = _unfilter(rows[:, 0], rows[:, 1:], bpp)
    if depth == 16:
        return out.view(">u2").astype(np.uint16).reshape(h, w, planes)
    return out.reshape(h, w, planes)
