"""Portable Float Map (``.pfm``): ``PF`` (RGB) or ``Pf`` (grey), width and height,
a scale whose sign gives the byte order (negative: little-endian), then float32
rows stored bottom to top."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..results import atomic_write_bytes
from ._errors import ImageFormatError, check_image_size, existing_file

__all__ = ["read_pfm", "write_pfm"]


def _tokens(data: bytes, count: int, path: Path) -> tuple[list[bytes], int]:
    """The first ``count`` whitespace-separated header tokens and the offset after
    the single whitespace byte that ends the last one."""
    toks, pos, n = [], 0, len(data)
    while len(toks) < count:
        while pos < n and data[pos : pos + 1].isspace():
            pos += 1
        start = pos
        while pos < n and not data[pos : pos + 1].isspace():
            pos += 1
        if start == pos:
            raise ImageFormatError(f"{path}: truncated PFM header")
        toks.append(data[start:pos])
    return toks, pos + 1


def read_pfm(path: str | os.PathLike) -> np.ndarray:
    """Read a PFM image as float32 ``[H, W, C]`` (C = 3 for ``PF``, 1 for ``Pf``),
    rows top to bottom. The absolute scale is not applied (it is conventionally 1);
    values are returned as stored (NaN / Inf included: radiance consumers check
    them). Raises ``ImageFormatError`` naming the file on a bad magic or header,
    a size above ``MAX_IMAGE_PIXELS``, or truncated data."""
    path = Path(path)
    existing_file(path, "PFM file")
    data = path.read_bytes()
    if data[:2] not in (b"PF", b"Pf"):
        raise ImageFormatError(f"{path}: not a PFM file (first bytes {data[:2]!r}, expected 'PF' or 'Pf')")
    (magic, w, h, scale), pos = _tokens(data, 4, path)
    if magic not in (b"PF", b"Pf"):
        raise ImageFormatError(f"{path}: not a PFM file (magic {magic[:8]!r}, expected 'PF' or 'Pf')")
    try:
        w, h, scale = int(w), int(h), float(scale)
    except ValueError as err:
        raise ImageFormatError(f"{path}: bad PFM header ({err})") from None
    if w <= 0 or h <= 0 or scale == 0 or not np.isfinite(scale):
        raise ImageFormatError(f"{path}: bad PFM header (size {w}x{h}, scale {scale})")
    c = 3 if magic == b"PF" else 1
    check_image_size(path, h, w, c, "the PFM header")
    need = w * h * c * 4
    if len(data) - pos < need:
        raise ImageFormatError(f"{path}: truncated PFM data ({len(data) - pos} bytes, expected {need})")
    dt = np.dtype("<f4" if scale < 0 else ">f4")
    img = np.frombuffer(data, dt, count=w * h * c, offset=pos).reshape(h, w, c)
    return np.ascontiguousarray(img[::-1], dtype=np.float32)


def write_pfm(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an ``[H, W]``, ``[H, W, 1]`` or ``[H, W, 3]`` float image as little-endian PFM, atomically."""
    path = Path(path)
    img = np.asarray(image, np.float32)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[-1] not in (1, 3):
        raise ValueError(f"{path}: PFM image must be [H, W], [H, W, 1] or [H, W, 3], got {img.shape}")
    h, w, c = img.shape
    head = f"{'PF' if c == 3 else 'Pf'}\n{w} {h}\n-1.0\n".encode()
    atomic_write_bytes(path, lambda fh: (fh.write(head), fh.write(img[::-1].astype("<f4").tobytes())))
