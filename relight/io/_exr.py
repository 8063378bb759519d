"""OpenEXR reading and writing through the official bindings (OpenEXR >= 3.3,
the ``OpenEXR.File`` / ``OpenEXR.Part`` API).

Conventions:

* Pixels are returned as numpy arrays ``[H, W, C]`` (float32 by default) in the
  channel order asked for; EXR itself stores channels alphabetically, so the
  default order is ``R, G, B[, A]`` when present, else ``Y``, else the file's
  (alphabetical) order.
* Metadata round-trips through the header: EXR-native values (str, int, float,
  float32/float64/int32 vectors of length 2 or 3, 3x3 and 4x4 matrices) are
  stored as EXR attributes; anything JSON-serialisable besides (dict, list,
  tuple, bool, None, numpy scalars and other arrays) is stored as a string
  attribute ``"json:" + json.dumps(value)`` and decoded on reading. A plain
  string that itself starts with ``"json:"`` is JSON-quoted on writing so it
  reads back unchanged.
* Writes are atomic (temporary file in the same folder, then ``os.replace``).
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import OpenEXR

from ..results import atomic_path
from ._errors import ImageFormatError, check_image_size, existing_file

__all__ = [
    "ExrPart",
    "exr_header",
    "read_exr",
    "read_exr_channels",
    "read_exr_parts",
    "write_exr",
    "write_exr_channels",
    "write_exr_parts",
]

_JSON_PREFIX = "json:"

# Header keys the writer controls itself (from the pixel arrays and arguments);
# a header copied from a file that was read is accepted and these are dropped.
_STRUCTURAL_KEYS = frozenset(
    {"channels", "dataWindow", "displayWindow", "chunkCount", "type", "tiles", "name", "version", "compression"}
)

_COMPRESSION = {
    "none": OpenEXR.NO_COMPRESSION,
    "rle": OpenEXR.RLE_COMPRESSION,
    "zips": OpenEXR.ZIPS_COMPRESSION,
    "zip": OpenEXR.ZIP_COMPRESSION,
    "piz": OpenEXR.PIZ_COMPRESSION,
    "pxr24": OpenEXR.PXR24_COMPRESSION,
    "b44": OpenEXR.B44_COMPRESSION,
    "b44a": OpenEXR.B44A_COMPRESSION,
    "dwaa": OpenEXR.DWAA_COMPRESSION,
    "dwab": OpenEXR.DWAB_COMPRESSION,
}


@dataclasses.dataclass(frozen=True)
class ExrPart:
    """One part of a (multi-part) EXR file.

    Attributes:
        channels: channel name -> 2-D array ``[H, W]`` (float32, float16 or uint32).
        header: user metadata (decoded as described in the module docstring)
            plus, when read from a file, the EXR structural attributes.
        name: the part's name (multi-part files require distinct names).
    """

    channels: dict[str, np.ndarray]
    header: dict = dataclasses.field(default_factory=dict)
    name: str = ""


# --------------------------------------------------------------------- header


def _encode_value(key: str, value):
    """EXR-native values pass through; the rest is stored as a json string."""
    if isinstance(value, str):
        return _JSON_PREFIX + json.dumps(value) if value.startswith(_JSON_PREFIX) else value
    if isinstance(value, bool) or value is None:
        return _JSON_PREFIX + json.dumps(value)
    if isinstance(value, int) and -(2**31) <= value < 2**31:
        return value
    if isinstance(value, float):
        return value
    if isinstance(value, np.generic):
        return _encode_value(key, value.item())
    if isinstance(value, np.ndarray):
        native = (
            (value.shape in {(2,), (3,)} and value.dtype in (np.float32, np.float64, np.int32))
            or (value.shape in {(3, 3), (4, 4)} and value.dtype in (np.float32, np.float64))
        )
        if native:
            return value
        value = value.tolist()
    if hasattr(OpenEXR, type(value).__name__) and not isinstance(value, (list, tuple, dict)):
        return value  # an OpenEXR attribute object (Compression, TileDescription, ...)
    try:
        return _JSON_PREFIX + json.dumps(value)
    except TypeError as err:
        raise TypeError(
            f"EXR header attribute {key!r}: value of type {type(value).__name__} is neither an EXR "
            "attribute type nor JSON-serialisable"
        ) from err


def _decode_header(header: Mapping) -> dict:
    out = {}
    for key, value in header.items():
        if isinstance(value, str) and value.startswith(_JSON_PREFIX):
            try:
                value = json.loads(value[len(_JSON_PREFIX):])
            except json.JSONDecodeError:
                pass  # written by another tool: keep the string as it is
        out[key] = value
    return out


def _encode_header(header: Mapping | None, compression: str, tile_size: int | tuple[int, int] | None) -> dict:
    out = {}
    for key, value in (header or {}).items():
        if key in _STRUCTURAL_KEYS:
            continue
        out[str(key)] = _encode_value(str(key), value)
    try:
        out["compression"] = _COMPRESSION[compression.lower()]
    except KeyError:
        raise ValueError(f"unknown EXR compression {compression!r}; expected one of {sorted(_COMPRESSION)}") from None
    if tile_size is None:
        out["type"] = OpenEXR.scanlineimage
    else:
        tx, ty = (tile_size, tile_size) if isinstance(tile_size, int) else tile_size
        tiles = OpenEXR.TileDescription()
        tiles.xSize, tiles.ySize, tiles.mode = int(tx), int(ty), OpenEXR.ONE_LEVEL
        out["type"] = OpenEXR.tiledimage
        out["tiles"] = tiles
    return out


# ---------------------------------------------------------------------- read


def _open_file(path: Path, header_only: bool) -> OpenEXR.File:
    try:
        return OpenEXR.File(str(path), separate_channels=True, header_only=header_only)
    except MemoryError:
        raise
    except Exception as err:  # the bindings raise RuntimeError/ValueError
        raise ImageFormatError(f"{path}: corrupt or truncated OpenEXR file ({err})") from err


def _check_sizes(f: OpenEXR.File, path: Path) -> None:
    """Every part's data window within ``MAX_IMAGE_PIXELS``, read from the header
    before the bindings allocate the pixel buffers it declares."""
    for i in range(len(f.parts)):
        try:
            (x0, y0), (x1, y1) = (np.asarray(c, np.int64) for c in f.header(i)["dataWindow"])
        except Exception as err:
            raise ImageFormatError(f"{path}: part {i} has no readable dataWindow ({err})") from err
        check_image_size(path, int(y1 - y0 + 1), int(x1 - x0 + 1), what=f"part {i}'s dataWindow")


def _open(path: Path, header_only: bool = False) -> OpenEXR.File:
    existing_file(path, "EXR file")
    if not OpenEXR.isOpenExrFile(str(path)):
        with open(path, "rb") as fh:
            magic = fh.read(4)
        raise ImageFormatError(f"{path}: not an OpenEXR file (magic bytes {magic!r}, expected b'v/1\\x01')")
    head = _open_file(path, header_only=True)
    _check_sizes(head, path)
    return head if header_only else _open_file(path, header_only=False)


def _num_parts(f: OpenEXR.File) -> int:
    return len(f.parts)


def _part_channels(f: OpenEXR.File, path: Path, part: int) -> dict[str, np.ndarray]:
    n = _num_parts(f)
    if n == 0:
        # The bindings report a pixel-data failure by leaving no parts.
        raise ImageFormatError(f"{path}: corrupt or truncated OpenEXR file (no readable part)")
    if not 0 <= part < n:
        raise ImageFormatError(f"{path}: part {part} requested but the file has {n} part(s)")
    try:
        chans = f.channels(part)
    except Exception as err:
        raise ImageFormatError(f"{path}: corrupt or truncated OpenEXR file ({err})") from err
    out = {}
    for name, ch in chans.items():
        px = ch.pixels
        if px is None:
            raise ImageFormatError(f"{path}: channel {name!r} of part {part} has no pixel data (truncated file?)")
        if ch.xSampling != 1 or ch.ySampling != 1:
            raise ImageFormatError(
                f"{path}: channel {name!r} is subsampled ({ch.xSampling}x{ch.ySampling}); "
                "only full-resolution channels are supported"
            )
        out[name] = np.asarray(px)
    return out


def exr_header(path: str | os.PathLike, part: int = 0) -> dict:
    """The header of one part (decoded metadata + EXR attributes), without pixels."""
    path = Path(path)
    f = _open(path, header_only=True)
    n = _num_parts(f)
    if not 0 <= part < n:
        raise ImageFormatError(f"{path}: part {part} requested but the file has {n} part(s)")
    return _decode_header(f.header(part))


def read_exr_channels(path: str | os.PathLike, part: int = 0) -> tuple[dict[str, np.ndarray], dict]:
    """Every channel of one part in its stored dtype, and the decoded header.

    Returns:
        ``(channels, header)``: channel name -> ``[H, W]`` array (float16,
        float32 or uint32, as stored), and the header dict.
    """
    path = Path(path)
    f = _open(path)
    chans = _part_channels(f, path, part)
    return chans, _decode_header(f.header(part))


def read_exr_parts(path: str | os.PathLike) -> list[ExrPart]:
    """Every part of a (multi-part) EXR file, each with its channels and header."""
    path = Path(path)
    f = _open(path)
    n = _num_parts(f)
    if n == 0:
        raise ImageFormatError(f"{path}: corrupt or truncated OpenEXR file (no readable part)")
    parts = []
    for i in range(n):
        header = _decode_header(f.header(i))
        parts.append(ExrPart(_part_channels(f, path, i), header, str(header.get("name", ""))))
    return parts


def _default_order(names: Sequence[str]) -> list[str]:
    if {"R", "G", "B"} <= set(names):
        return ["R", "G", "B"] + (["A"] if "A" in names else [])
    if "Y" in names:
        return ["Y"]
    return sorted(names)


def read_exr(
    path: str | os.PathLike,
    channels: Sequence[str] | None = None,
    part: int = 0,
    dtype=np.float32,
) -> np.ndarray:
    """Read an OpenEXR image as ``[H, W, C]`` (float32 unless ``dtype`` says otherwise).

    Args:
        path: the .exr file.
        channels: channel names in the order wanted (e.g. ``["R", "G", "B"]``,
            ``["normal.X", "normal.Y", "normal.Z"]``); default ``R, G, B[, A]``,
            else ``Y``, else all channels alphabetically.
        part: which part of a multi-part file.
        dtype: output dtype (half channels are widened exactly to float32).

    Raises:
        FileNotFoundError: no such file.
        ImageFormatError: not an EXR, corrupt/truncated, or a requested channel
            is missing (the message lists the channels present).
    """
    path = Path(path)
    chans, _ = read_exr_channels(path, part)
    names = list(chans) if channels is None else list(channels)
    if channels is None:
        names = _default_order(names)
    missing = [c for c in names if c not in chans]
    if missing:
        raise ImageFormatError(
            f"{path}: channel(s) {missing} not found in part {part}; the file has {sorted(chans)}"
        )
    if not names:
        raise ImageFormatError(f"{path}: part {part} has no channels")
    return np.stack([chans[c].astype(dtype, copy=False) for c in names], axis=-1)


# --------------------------------------------------------------------- write


def _default_names(c: int) -> list[str]:
    names = {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}.get(c)
    if names is None:
        raise ValueError(f"an image with {c} channels needs explicit channel names (channels=[...])")
    return names


def _prepare_channel(path: Path, name: str, px, half: bool, arg: str) -> np.ndarray:
    """One channel as the dtype it is stored in. ``half``: NaN and values beyond
    half's range (Inf included) are refused; float32: finite values beyond its
    range are refused (they would be stored as Inf), NaN and Inf are stored as
    they are. ValueError naming the file, the argument and the channel."""
    px = np.asarray(px)
    if px.ndim != 2:
        raise ValueError(f"{path}: channel {name!r} must be 2-D [H, W], got shape {px.shape}")
    if px.dtype == np.uint32:
        return np.ascontiguousarray(px)
    if not np.issubdtype(px.dtype, np.floating) and not np.issubdtype(px.dtype, np.integer) and px.dtype != bool:
        raise ValueError(f"{path}: channel {name!r} has unsupported dtype {px.dtype}")
    where = f"{path}: argument {arg!r}, channel {name!r}"
    if half and np.isnan(px).any():
        raise ValueError(f"{where} has {int(np.isnan(px).sum())} NaN values; half=True refuses them")
    mag = np.abs(px[np.isfinite(px)] if np.issubdtype(px.dtype, np.floating) else px.astype(np.float64))
    top = float(mag.max(initial=0.0))
    limit = float(np.finfo(np.float16 if half else np.float32).max)
    if half and (top > limit or np.isinf(px).any()):
        big = float(np.abs(px).max())
        raise ValueError(f"{where} has values up to {big:.4g}, beyond float16's {limit}; "
                         "write it as float (half=False)")
    if not half and top > limit:
        raise ValueError(f"{where} has values up to {top:.4g}, beyond float32's {limit:.4g} (they would be "
                         "stored as Inf)")
    return np.ascontiguousarray(px, dtype=np.float16 if half else np.float32)


def _prepare_channels(path: Path, channels: Mapping[str, np.ndarray], half: bool,
                      arg: str = "channels") -> dict[str, np.ndarray]:
    if not channels:
        raise ValueError(f"{path}: no channels to write")
    out = {str(k): _prepare_channel(path, str(k), v, half, arg) for k, v in channels.items()}
    shapes = {v.shape for v in out.values()}
    if len(shapes) != 1:
        raise ValueError(f"{path}: channels have different shapes {sorted(shapes)}")
    return out


def _write_file(path: Path, f: OpenEXR.File) -> None:
    with atomic_path(path) as tmp:
        f.write(str(tmp))


def write_exr_channels(
    path: str | os.PathLike,
    channels: Mapping[str, np.ndarray],
    header: Mapping | None = None,
    half: bool = False,
    tile_size: int | tuple[int, int] | None = None,
    compression: str = "zip",
) -> None:
    """Write named ``[H, W]`` channels to a single-part EXR, atomically.

    Args:
        channels: name -> 2-D array; float arrays are stored as float32 (or
            float16 with ``half=True``), uint32 arrays as UINT.
        header: metadata to store (see the module docstring for types).
        half: store float channels as IEEE half (10-bit mantissa, max 65504);
            NaN, Inf and values beyond 65504 raise ValueError. Without it,
            finite values beyond float32's range raise (NaN / Inf are stored).
        tile_size: ``None`` for a scanline image, else the tile edge (or
            ``(x, y)``) of a single-level tiled image.
        compression: one of none, rle, zips, zip, piz, pxr24, b44, b44a, dwaa, dwab
            (the lossy ones are pxr24, b44, b44a, dwaa, dwab).
    """
    _write_single(Path(path), channels, header, half, tile_size, compression, "channels")


def _write_single(path: Path, channels, header, half, tile_size, compression, arg: str) -> None:
    """Write a single-part EXR; ``arg`` names the caller's pixel argument in errors."""
    chans = _prepare_channels(path, channels, half, arg)
    _write_file(path, OpenEXR.File(_encode_header(header, compression, tile_size), chans))


def write_exr(
    path: str | os.PathLike,
    image: np.ndarray,
    header: Mapping | None = None,
    half: bool = False,
    channels: Sequence[str] | None = None,
    tile_size: int | tuple[int, int] | None = None,
    compression: str = "zip",
) -> None:
    """Write an ``[H, W]`` or ``[H, W, C]`` image to an EXR file, atomically.

    Channel names default to ``Y`` (C = 1), ``R, G, B`` (C = 3) or
    ``R, G, B, A`` (C = 4); other channel counts need ``channels``. The other
    arguments are those of :func:`write_exr_channels`.
    """
    path = Path(path)
    image = np.asarray(image)
    if image.ndim == 2:
        image = image[..., None]
    if image.ndim != 3:
        raise ValueError(f"{path}: image must be [H, W] or [H, W, C], got shape {image.shape}")
    names = list(channels) if channels is not None else _default_names(image.shape[-1])
    if len(names) != image.shape[-1] or len(set(names)) != len(names):
        raise ValueError(f"{path}: {len(names)} distinct channel names needed for {image.shape[-1]} channels, "
                         f"got {names}")
    _write_single(path, {n: image[..., i] for i, n in enumerate(names)}, header, half, tile_size, compression,
                  "image")


def write_exr_parts(
    path: str | os.PathLike,
    parts: Sequence[ExrPart],
    half: bool = False,
    tile_size: int | tuple[int, int] | None = None,
    compression: str = "zip",
) -> None:
    """Write a multi-part EXR file (each part its own channels, header and name), atomically."""
    path = Path(path)
    if not parts:
        raise ValueError(f"{path}: no parts to write")
    names = [p.name or f"part{i}" for i, p in enumerate(parts)]
    if len(set(names)) != len(names):
        raise ValueError(f"{path}: part names must be distinct, got {names}")
    exr_parts = [
        OpenEXR.Part(_encode_header(p.header, compression, tile_size),
                     _prepare_channels(path, p.channels, half, f"parts[{i}]"), n)
        for i, (p, n) in enumerate(zip(parts, names, strict=True))
    ]
    _write_file(path, OpenEXR.File(exr_parts))
