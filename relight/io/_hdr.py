"""Radiance RGBE (``.hdr``) reading and writing (Ward, "Real Pixels",
Graphics Gems II, 1991; the Radiance file-format notes).

Reading accepts the three pixel encodings found in the wild: flat (4 bytes per
pixel), the old run-length encoding (a pixel ``1 1 1 n`` repeats the previous
pixel ``n << shift`` times) and the new per-component run-length encoding
(scanlines starting ``2 2 hi lo``). Any orientation line (``-Y H +X W`` is the
standard one; ``+Y``, ``-X`` and transposed ``X``-first layouts too) is turned
into rows top-to-bottom, columns left-to-right.

Decoding follows Radiance's ``colr_color``: a component is
``(m + 0.5) * 2^(e - 136)`` for ``e > 0`` (the mantissa's mid-point, which
halves the quantisation error of truncating encoders), and 0 for ``e = 0``.
The ``EXPOSURE`` header is reported, not applied, as most readers do.

Limits: a declared size above ``MAX_IMAGE_PIXELS`` (``relight/io/_errors.py``,
2^28 pixels) is refused before any pixel buffer is allocated. The largest
RGBE value is ``255.5 * 2^119`` (about 1.7e38, below float32's 3.4e38), so the
reader never returns Inf; ``write_hdr`` refuses values above ``RGBE_MAX`` (the
largest value the encoding holds) instead of letting the exponent byte wrap.
Radiance consumers (``check_radiance``) refuse values above ``MAX_RADIANCE``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ..results import atomic_write_bytes
from ._errors import ImageFormatError, check_image_size, existing_file

__all__ = ["RGBE_MAX", "read_hdr", "read_hdr_header", "write_hdr"]

# The largest value RGBE stores: mantissa 255 at exponent byte 255, decoded at the mantissa's mid-point
# (Radiance's colr_color): 255.5 * 2^(255 - 136). Ward's encoder gives exponent byte 256 (which wraps to 0,
# black) for anything at or above 2^127, so write_hdr refuses values above this instead.
RGBE_MAX = float(np.ldexp(255.5, 255 - 136))

_MAGICS = (b"#?RADIANCE", b"#?RGBE")
_RES_RE = re.compile(rb"^([+-])([XY]) (\d+) ([+-])([XY]) (\d+)$")


def _parse_header(data: bytes, path: Path) -> tuple[dict, tuple, int]:
    """Header dict, orientation ((sign, axis, n), (sign, axis, n)) and the data offset."""
    if not data.startswith(_MAGICS):
        raise ImageFormatError(f"{path}: not a Radiance HDR file (first bytes {data[:10]!r}, expected '#?RADIANCE')")
    end = data.find(b"\n\n")
    if end < 0:
        raise ImageFormatError(f"{path}: truncated Radiance header (no blank line ending it)")
    header: dict = {}
    for line in data[:end].split(b"\n")[1:]:
        if line.startswith(b"#") or b"=" not in line:
            continue
        key, _, value = line.partition(b"=")
        key_s, value_s = key.decode("ascii", "replace").strip(), value.decode("ascii", "replace").strip()
        if key_s == "EXPOSURE":  # cumulative, per the format notes
            try:
                exposure = float(value_s)
            except ValueError:
                raise ImageFormatError(f"{path}: header EXPOSURE={value_s!r} is not a number") from None
            if not (np.isfinite(exposure) and exposure > 0):
                raise ImageFormatError(f"{path}: header EXPOSURE={value_s!r} must be a positive finite number")
            header[key_s] = header.get(key_s, 1.0) * exposure
        else:
            header[key_s] = value_s
    fmt = header.get("FORMAT", "32-bit_rle_rgbe")
    if fmt != "32-bit_rle_rgbe":
        raise ImageFormatError(f"{path}: FORMAT={fmt} not supported (expected 32-bit_rle_rgbe)")
    res_end = data.find(b"\n", end + 2)
    if res_end < 0:
        raise ImageFormatError(f"{path}: truncated Radiance header (no resolution line)")
    m = _RES_RE.match(data[end + 2 : res_end].strip())
    if m is None or m.group(2) == m.group(5):
        raise ImageFormatError(
            f"{path}: bad resolution line {data[end + 2:res_end]!r} (expected e.g. '-Y 512 +X 1024')"
        )
    orient = ((m.group(1), m.group(2), int(m.group(3))), (m.group(4), m.group(5), int(m.group(6))))
    if orient[0][2] <= 0 or orient[1][2] <= 0:
        raise ImageFormatError(f"{path}: empty image in resolution line")
    check_image_size(path, orient[0][2], orient[1][2], 3, "the resolution line")
    return header, orient, res_end + 1


def read_hdr_header(path: str | os.PathLike) -> dict:
    """The header variables of a Radiance file (``FORMAT``, ``EXPOSURE``, ...), plus
    ``"shape"``: ``(H, W)`` as :func:`read_hdr` returns it."""
    path = Path(path)
    with open(path, "rb") as fh:
        data = fh.read(65536)
    header, orient, _ = _parse_header(data, path)
    h, w = (orient[0][2], orient[1][2]) if orient[0][1] == b"Y" else (orient[1][2], orient[0][2])
    return {**header, "shape": (h, w)}


def _decode_new_rle(buf: memoryview, pos: int, width: int, path: Path, line: int) -> tuple[np.ndarray, int]:
    """One new-style RLE scanline starting at ``pos`` (after the 4-byte marker)."""
    out = bytearray(4 * width)
    n = len(buf)
    for comp in range(4):
        x, base = 0, comp * width
        while x < width:
            if pos >= n:
                raise ImageFormatError(f"{path}: truncated RLE data in scanline {line}")
            count = buf[pos]
            pos += 1
            if count > 128:  # a run of one repeated byte
                count -= 128
                if x + count > width or pos >= n:
                    raise ImageFormatError(f"{path}: corrupt RLE run in scanline {line} (overruns the width)")
                out[base + x : base + x + count] = bytes((buf[pos],)) * count
                pos += 1
            else:  # count literal bytes
                if count == 0 or x + count > width or pos + count > n:
                    raise ImageFormatError(f"{path}: corrupt or truncated RLE data in scanline {line}")
                out[base + x : base + x + count] = buf[pos : pos + count]
                pos += count
            x += count
    # planar RRR..GGG..BBB..EEE.. -> interleaved RGBE
    return np.frombuffer(bytes(out), np.uint8).reshape(4, width).T, pos


def _decode_old(buf: memoryview, pos: int, width: int, path: Path, line: int, prev: np.ndarray | None):
    """Flat or old-style RLE scanline; returns ([width, 4] bytes, new pos, last pixel)."""
    n = len(buf)
    chunk = np.frombuffer(buf[pos : min(n, pos + 4 * width)], np.uint8)
    if chunk.size == 4 * width:
        px = chunk.reshape(width, 4)
        if not np.any((px[:, 0] == 1) & (px[:, 1] == 1) & (px[:, 2] == 1)):
            return px, pos + 4 * width, px[-1]  # flat: the common case, vectorised
    out = np.empty((width, 4), np.uint8)
    x, shift = 0, 0
    last = prev
    while x < width:
        if pos + 4 > n:
            raise ImageFormatError(f"{path}: truncated pixel data in scanline {line}")
        p = buf[pos : pos + 4]
        pos += 4
        if p[0] == 1 and p[1] == 1 and p[2] == 1:
            if last is None:
                raise ImageFormatError(f"{path}: old-style RLE repeat with no previous pixel (scanline {line})")
            count = p[3] << shift
            if x + count > width:
                raise ImageFormatError(f"{path}: corrupt old-style RLE run in scanline {line} (overruns the width)")
            out[x : x + count] = last
            x += count
            shift += 8
        else:
            last = np.frombuffer(bytes(p), np.uint8)
            out[x] = last
            x += 1
            shift = 0
    return out, pos, last


def _rgbe_to_float(rgbe: np.ndarray) -> np.ndarray:
    e = rgbe[..., 3].astype(np.int32)
    scale = np.where(e > 0, np.ldexp(np.float32(1.0), e - 136), 0).astype(np.float32)
    return ((rgbe[..., :3].astype(np.float32) + 0.5) * scale[..., None]).astype(np.float32)


def read_hdr(path: str | os.PathLike) -> np.ndarray:
    """Read a Radiance RGBE ``.hdr`` image as float32 ``[H, W, 3]`` (rows top to bottom).

    Units are those of the file (for light probes: relative radiance); values
    are finite, at most ``RGBE_MAX``. Raises ``ImageFormatError`` naming the
    file on a bad magic, an unsupported format, a bad header value
    (``EXPOSURE``), a bad resolution line, a declared size above
    ``MAX_IMAGE_PIXELS`` (checked before allocating), truncated or corrupt
    pixel data.
    """
    path = Path(path)
    existing_file(path, "HDR file")
    data = path.read_bytes()
    _, (slow, fast), pos = _parse_header(data, path)
    n_lines, width = slow[2], fast[2]
    if len(data) - pos < 4 * n_lines:  # every scanline takes >= 4 bytes (one pixel or an RLE marker)
        raise ImageFormatError(f"{path}: truncated pixel data ({len(data) - pos} bytes for {n_lines} scanlines)")
    buf = memoryview(data)
    lines = np.empty((n_lines, width, 4), np.uint8)
    prev = None
    for y in range(n_lines):
        if (
            8 <= width < 0x8000
            and pos + 4 <= len(buf)
            and buf[pos] == 2
            and buf[pos + 1] == 2
            and not buf[pos + 2] & 0x80
        ):
            if (buf[pos + 2] << 8 | buf[pos + 3]) != width:
                raise ImageFormatError(f"{path}: RLE scanline {y} declares width "
                                       f"{buf[pos + 2] << 8 | buf[pos + 3]}, header says {width}")
            lines[y], pos = _decode_new_rle(buf, pos + 4, width, path, y)
            prev = lines[y, -1]
        else:
            lines[y], pos, prev = _decode_old(buf, pos, width, path, y, prev)
    img = _rgbe_to_float(lines)  # [slow, fast, 3]
    # Orientation: the first axis listed is the slow (scanline) one.
    if slow[1] == b"X":  # transposed layout: scanlines are columns
        img = img.transpose(1, 0, 2)
        y_sign, x_sign = fast[0], slow[0]
    else:
        y_sign, x_sign = slow[0], fast[0]
    if y_sign == b"+":  # '+Y' lists rows bottom to top
        img = img[::-1]
    if x_sign == b"-":
        img = img[:, ::-1]
    return np.ascontiguousarray(img)


def _float_to_rgbe(img: np.ndarray) -> np.ndarray:
    """Ward's encoding: shared exponent of the largest component, mantissas truncated."""
    img = img.astype(np.float64)
    peak = img.max(axis=-1)
    mant, exp = np.frexp(peak)  # peak = mant * 2^exp, mant in [0.5, 1)
    ok = peak >= 1e-32  # below this the pixel is black (Radiance's threshold)
    scale = np.where(ok, mant * 256.0 / np.where(ok, peak, 1.0), 0.0)
    rgb = np.clip(np.floor(img * scale[..., None]), 0, 255).astype(np.uint8)
    e = np.where(ok, exp + 128, 0).astype(np.uint8)
    return np.concatenate([rgb, e[..., None]], axis=-1)


def _encode_rle_component(row: np.ndarray) -> bytes:
    """New-style RLE of one component row: runs of >= 4 equal bytes as (128 + n, v),
    everything else as literal blocks of <= 128 bytes."""
    width = row.size
    change = np.flatnonzero(np.diff(row.astype(np.int16)) != 0) + 1
    starts = np.concatenate([[0], change])
    lengths = np.diff(np.concatenate([starts, [width]]))
    out = bytearray()
    lit_from = 0
    for s, n in zip(starts[lengths >= 4].tolist(), lengths[lengths >= 4].tolist(), strict=True):
        for a in range(lit_from, s, 128):  # literal bytes before this run
            b = min(a + 128, s)
            out.append(b - a)
            out += row[a:b].tobytes()
        v = int(row[s])
        lit_from = s + n
        while n > 0:
            k = min(n, 127)
            out += bytes((128 + k, v))
            n -= k
    for a in range(lit_from, width, 128):
        b = min(a + 128, width)
        out.append(b - a)
        out += row[a:b].tobytes()
    return bytes(out)


def write_hdr(path: str | os.PathLike, image: np.ndarray, rle: bool = True, exposure: float | None = None) -> None:
    """Write a float ``[H, W, 3]`` image (non-negative, finite, at most
    ``RGBE_MAX``: ValueError naming ``image`` otherwise) as Radiance RGBE, atomically.

    Args:
        rle: new-style run-length encoding (the default, as Radiance writes);
            ``False`` writes flat 4-byte pixels. Widths outside [8, 32767]
            cannot be run-length encoded and are written flat.
        exposure: if given, written as the ``EXPOSURE`` header (informational).

    The encoding keeps 8 mantissa bits of the largest component: relative error
    <= 2^-8 of the pixel's largest component.
    """
    path = Path(path)
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[-1] != 3:
        raise ValueError(f"{path}: HDR image must be [H, W, 3], got shape {img.shape}")
    if not np.isfinite(img).all() or (img < 0).any():
        raise ValueError(f"{path}: HDR image must be finite and non-negative (RGBE cannot store NaN/Inf/negatives)")
    if img.size and img.max() > RGBE_MAX:
        raise ValueError(f"{path}: argument 'image' has values up to {float(img.max()):.4g}, beyond RGBE's largest "
                         f"value {RGBE_MAX:.4g} (its exponent byte would wrap); scale the image down")
    h, w, _ = img.shape
    rgbe = _float_to_rgbe(img)
    head = b"#?RADIANCE\n# Written by relight.io\nFORMAT=32-bit_rle_rgbe\n"
    if exposure is not None:
        head += f"EXPOSURE={float(exposure):.9g}\n".encode()
    head += f"\n-Y {h} +X {w}\n".encode()

    def write(fh):
        fh.write(head)
        if not rle or not 8 <= w < 0x8000:
            fh.write(rgbe.tobytes())
            return
        marker = bytes((2, 2, w >> 8, w & 0xFF))
        for y in range(h):
            fh.write(marker + b"".join(_encode_rle_component(rgbe[y, :, c]) for c in range(4)))

    atomic_write_bytes(path, write)
