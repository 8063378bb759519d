"""8- and 16-bit PNG through pypng (pure Python). Pillow reduces 16-bit PNGs to
8 bits, which would throw away the low byte of every DiLiGenT capture, so it is
not used here."""

from __future__ import annotations

import os
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
        w, h, rows, info = png.Reader(bytes=data).asDirect()
        # The header's size, before any row is decoded (a corrupt IHDR declares up to 2^31 x 2^31).
        check_image_size(path, h, w, info["planes"], "the PNG header")
        if shape is not None and (h, w) != tuple(shape):
            raise ImageFormatError(f"{path}: the PNG header says {w}x{h} pixels, expected {shape[1]}x{shape[0]}")
        if max_pixels is not None and h * w > max_pixels:
            raise ImageFormatError(f"{path}: the PNG header says {w}x{h} pixels, more than the {max_pixels} "
                                   "this file may have")
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
    h, w, c = img.shape
    writer = png.Writer(
        width=w, height=h, greyscale=c <= 2, alpha=c in (2, 4), bitdepth=16 if img.dtype == np.uint16 else 8
    )
    rows = np.ascontiguousarray(img).reshape(h, w * c)
    atomic_write_bytes(path, lambda fh: writer.write(fh, rows))
