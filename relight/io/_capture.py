"""Capture folders: one OpenEXR per view and light, plus ``rig.json``,
``cameras.json`` and ``capture.json``.

Layout (format version 1)::

    folder/capture.json     {"format": "relight-capture", "version": 1,
                             "n_views": V, "n_lights": L, "sample_shape": [H, W],
                             "channels": ["R", "G", "B"], "half": false,
                             "has_valid": true, "files": "views/v{view:03d}/l{light:03d}.exr",
                             "metadata": {...}}           (exposure, noise, units, ...)
    folder/rig.json         {"directions" | "positions": [[x, y, z], ...] (L rows),
                             "intensities": [[r, g, b], ...] (L rows), ...}  any extra keys kept
                            (stage.rig_to_dict's schema when written from a stage.Rig)
    folder/cameras.json     [{"name": ..., ...}, ...]    (V entries: stage.camera_to_dict, or free-form)
    folder/views/v000/l000.exr ...                       channels R, G, B [+ "valid"]

Each EXR holds one view under one light: ``[H, W]`` per channel with
``H * W = P`` samples (an image-space capture uses its image size; a
texel-space capture its texel grid, or ``[1, P]``). An optional ``valid``
channel (half, 0 or 1) is the validity mask (not shadowed / occluded /
saturated). Each EXR's header also records its view and light index, so a
misplaced file is detected.

The whole folder is written under a temporary name next to the target and
renamed into place, so a crash never leaves a half-written capture (an
existing capture at the target is replaced only once the new one is complete).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import secrets
import shutil
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

import stage

from ..results import MANIFEST, open_result_set, swap_into
from ..results import folder_mode as _folder_mode
from ._errors import (
    ImageFormatError,
    check_image_size,
    check_radiance,
    format_version,
    path_inside,
    path_template,
    set_refusal_as,
)
from ._exr import read_exr_channels, write_exr_channels
from ._json import read_json, write_json

__all__ = ["CaptureData", "CaptureReader", "open_capture", "read_capture", "write_capture"]

_FORMAT = "relight-capture"
_VERSION = 1
_FILES = "views/v{view:03d}/l{light:03d}.exr"


@dataclasses.dataclass(frozen=True)
class CaptureData:
    """A capture as plain numpy arrays and dicts (adapt to ``stage.Capture``).

    Attributes:
        radiance: ``[V, L, P, C]`` float32 (or float16 if stored as half and read
            with ``dtype=None``), in the capture's radiance units.
        valid: ``[V, L, P]`` bool validity mask, or None if the capture has none.
        rig: the contents of ``rig.json`` (``directions`` or ``positions``
            ``[L, 3]`` and ``intensities`` ``[L, C]`` as numpy arrays).
        cameras: the contents of ``cameras.json`` (one dict per view).
        metadata: ``capture.json``'s ``metadata`` (exposure, noise, units...).
        sample_shape: ``(H, W)`` of each stored image, ``H * W = P``.
        lights: indices of the lights loaded (all by default).
        views: indices of the views loaded.
    """

    radiance: np.ndarray
    valid: np.ndarray | None
    rig: dict
    cameras: list
    metadata: dict
    sample_shape: tuple[int, int]
    lights: tuple[int, ...]
    views: tuple[int, ...]


def _rig_light_count(rig: object, where) -> int:
    if not isinstance(rig, Mapping):
        raise ImageFormatError(f"{where}: a rig must be a JSON object, got {type(rig).__name__}")
    for key in ("directions", "positions"):
        if key in rig:
            arr = _rig_array(rig, key, where)
            if arr.ndim != 2 or arr.shape[1] != 3:
                raise ImageFormatError(f"{where}: rig '{key}' must be [L, 3], got shape {arr.shape}")
            return arr.shape[0]
    raise ImageFormatError(f"{where}: rig needs 'directions' or 'positions' ([L, 3])")


def _rig_array(rig: Mapping, key: str, where) -> np.ndarray:
    """Field ``key`` of a rig dict as a finite float64 array (ImageFormatError naming the field)."""
    try:
        arr = np.asarray(rig[key], np.float64)
    except (TypeError, ValueError) as err:
        raise ImageFormatError(f"{where}: rig field {key!r} must be numbers ({err})") from None
    if not np.all(np.isfinite(arr)):
        raise ImageFormatError(f"{where}: rig field {key!r} has NaN or Inf values")
    return arr


def _count(info: Mapping, key: str, where) -> int:
    """A positive integer field of capture.json (a JSON integer, not a bool or a string)."""
    value = info.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ImageFormatError(f"{where}: field {key!r} must be a positive integer, got {value!r}")
    return value


@contextlib.contextmanager
def _atomic_folder(folder: Path) -> Iterator[Path]:
    """Yield a temporary folder next to ``folder`` (mode 0o777 less the umask);
    on success swap it into place with the result sets' one folder swap
    (:func:`relight.results.swap_into`: an atomic exchange, or the old
    capture moved aside, then deleted). Single files go through :func:`relight.results.atomic_path`."""
    parent = folder.parent if str(folder.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{folder}: cannot write, folder {parent} does not exist")
    tmp = parent / f".{folder.name}.{secrets.token_hex(6)}.tmp"
    tmp.mkdir(mode=_folder_mode())
    try:
        yield tmp
        if folder.exists() and not (folder / "capture.json").is_file():
            raise FileExistsError(f"{folder}: exists and is not a capture folder; refusing to replace it")
        swap_into(tmp, folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_capture(
    folder: str | os.PathLike,
    radiance: np.ndarray,
    rig: Mapping | stage.Rig,
    cameras: Sequence[Mapping | stage.Camera] | None = None,
    valid: np.ndarray | None = None,
    metadata: Mapping | None = None,
    sample_shape: tuple[int, int] | None = None,
    half: bool = False,
    channels: Sequence[str] | None = None,
) -> None:
    """Write a capture folder (see the module docstring), atomically.

    Args:
        radiance: ``[V, L, P, C]`` OLAT radiance (finite, non-negative).
        rig: a ``stage.Rig`` (stored as ``stage.rig_to_dict``), or a dict with
            ``directions`` or ``positions`` ``[L, 3]`` and ``intensities``
            ``[L, C]`` (extra keys, e.g. ``solid_angles``, kept).
        cameras: one ``stage.Camera`` (stored as ``stage.camera_to_dict``, named
            cam000, cam001, ...) or JSON-able dict per view (default:
            ``{"name": "view<i>"}``).
        valid: optional ``[V, L, P]`` bool mask.
        metadata: JSON-able dict (exposure, noise model, units...).
        sample_shape: ``(H, W)`` with ``H * W = P``; default ``(1, P)``.
        half: store radiance as half floats (halves the size; 11-bit precision).
        channels: channel names (default R, G, B for C = 3, Y for C = 1).
    """
    folder = Path(folder)
    if isinstance(rig, stage.Rig):
        rig = stage.rig_to_dict(rig)
    if cameras is not None:
        cameras = [stage.camera_to_dict(c, f"cam{i:03d}") if isinstance(c, stage.Camera) else c
                   for i, c in enumerate(cameras)]
    rad = np.asarray(radiance)
    if rad.ndim != 4:
        raise ValueError(f"{folder}: radiance must be [V, L, P, C], got shape {rad.shape}")
    n_views, n_lights, n_samples, n_ch = rad.shape
    check_radiance(rad, folder, "capture radiance")
    if _rig_light_count(rig, folder) != n_lights:
        raise ValueError(f"{folder}: rig has {_rig_light_count(rig, folder)} lights but radiance has {n_lights}")
    if "intensities" in rig and np.asarray(rig["intensities"]).shape[0] != n_lights:
        raise ValueError(f"{folder}: rig intensities have {np.asarray(rig['intensities']).shape[0]} rows, "
                         f"expected {n_lights}")
    cams = list(cameras) if cameras is not None else [{"name": f"view{v}"} for v in range(n_views)]
    if len(cams) != n_views:
        raise ValueError(f"{folder}: {len(cams)} cameras given for {n_views} views")
    shape = tuple(sample_shape) if sample_shape is not None else (1, n_samples)
    if len(shape) != 2 or shape[0] * shape[1] != n_samples:
        raise ValueError(f"{folder}: sample_shape {shape} does not hold {n_samples} samples")
    default_names = {1: ["Y"], 3: ["R", "G", "B"], 4: ["R", "G", "B", "A"]}
    names = list(channels) if channels is not None else default_names.get(n_ch)
    if names is None or len(names) != n_ch or "valid" in names:
        raise ValueError(f"{folder}: need {n_ch} channel names (not 'valid'), got {names}")
    if valid is not None:
        valid = np.asarray(valid, bool)
        if valid.shape != (n_views, n_lights, n_samples):
            raise ValueError(f"{folder}: valid mask must be {(n_views, n_lights, n_samples)}, got {valid.shape}")
    with _atomic_folder(folder) as tmp:
        for v in range(n_views):
            for l in range(n_lights):
                path = tmp / _FILES.format(view=v, light=l)
                path.parent.mkdir(parents=True, exist_ok=True)
                chans = {n: rad[v, l, :, i].reshape(shape) for i, n in enumerate(names)}
                if valid is not None:
                    chans["valid"] = valid[v, l].reshape(shape).astype(np.float16)
                header = {"relight.view": v, "relight.light": l}
                write_exr_channels(path, chans, header=header, half=half)
        write_json(tmp / "rig.json", rig, indent=1)
        write_json(tmp / "cameras.json", cams, indent=1)
        write_json(
            tmp / "capture.json",
            {
                "format": _FORMAT,
                "version": _VERSION,
                "n_views": n_views,
                "n_lights": n_lights,
                "sample_shape": list(shape),
                "channels": names,
                "half": bool(half),
                "has_valid": valid is not None,
                "files": _FILES,
                "metadata": dict(metadata or {}),
            },
            indent=1,
        )


def _load_json(path: Path):
    return read_json(path, "a capture folder needs capture.json, rig.json and cameras.json")


def _files_template(template: object, where: str) -> str:
    """capture.json's ``files``: a format string whose only fields are ``{view}``
    and ``{light}`` (with format specs), no attribute or index access."""
    return path_template(template, {"view": 0, "light": 0}, ("light",), where)


def _check_info(info: object, where: Path) -> Mapping:
    """capture.json's object, every field checked (ImageFormatError naming the file and the field)."""
    if not isinstance(info, Mapping):
        raise ImageFormatError(f"{where}: must be a JSON object, got {type(info).__name__}")
    if info.get("format") != _FORMAT:
        raise ImageFormatError(f"{where}: not a relight capture (format {info.get('format')!r})")
    format_version(info, where, _VERSION, default=_VERSION)
    _count(info, "n_views", where)
    _count(info, "n_lights", where)
    shape, channels = info.get("sample_shape"), info.get("channels")
    if not (isinstance(shape, list) and len(shape) == 2
            and all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in shape)):
        raise ImageFormatError(f"{where}: field 'sample_shape' must be [H, W] positive integers, got {shape!r}")
    check_image_size(where, shape[0], shape[1], what="field 'sample_shape'")
    if not (isinstance(channels, list) and channels and all(isinstance(c, str) and c for c in channels)
            and len(set(channels)) == len(channels) and "valid" not in channels):
        raise ImageFormatError(f"{where}: field 'channels' must be a list of distinct channel names "
                               f"(not 'valid'), got {channels!r}")
    for key in ("has_valid", "half"):
        if not isinstance(info.get(key, False), bool):
            raise ImageFormatError(f"{where}: field {key!r} must be true or false, got {info[key]!r}")
    if not isinstance(info.get("metadata", {}), Mapping):
        raise ImageFormatError(f"{where}: field 'metadata' must be a JSON object, got "
                               f"{type(info['metadata']).__name__}")
    return info


class CaptureReader:
    """Lazy access to a capture folder: nothing but the JSON files is read until
    asked, so stacks larger than memory can be streamed light by light or in
    sample chunks (:meth:`iter_lights`, :meth:`read` with ``samples=``): a
    ``relight.io.CaptureSource``.

    Attributes:
        folder, n_views, n_lights, n_samples, n_channels, sample_shape,
        channels, rig, cameras, metadata, has_valid.
    """

    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FileNotFoundError(f"{self.folder}: no such capture folder")
        # A capture written as a result set (relight simulate): its JSON files must be the set's own.
        if (self.folder / MANIFEST).is_file():
            with set_refusal_as(self.folder):
                rs = open_result_set(self.folder)
                rs.check([n for n in ("capture.json", "rig.json", "cameras.json") if n in rs.files])
        where = self.folder / "capture.json"
        info = _check_info(_load_json(where), where)
        self.n_views, self.n_lights = info["n_views"], info["n_lights"]
        self.sample_shape, self.channels = tuple(info["sample_shape"]), list(info["channels"])
        self.has_valid, self.half = info.get("has_valid", False), info.get("half", False)
        self.metadata = dict(info.get("metadata", {}))
        self._files = _files_template(info.get("files", _FILES), f"{where}: field 'files'")
        self.n_samples = self.sample_shape[0] * self.sample_shape[1]
        self.n_channels = len(self.channels)
        rig_path = self.folder / "rig.json"
        rig = _load_json(rig_path)
        n_rig = _rig_light_count(rig, rig_path)
        if n_rig != self.n_lights:
            raise ImageFormatError(
                f"{rig_path}: {n_rig} lights in the rig but capture.json declares {self.n_lights} light images per view"
            )
        rig = dict(rig)
        for key in ("directions", "positions", "intensities", "solid_angles"):
            if key in rig:
                rig[key] = _rig_array(rig, key, rig_path)
        if "intensities" in rig and (rig["intensities"].ndim == 0 or rig["intensities"].shape[0] != self.n_lights):
            raise ImageFormatError(f"{rig_path}: 'intensities' has shape {rig['intensities'].shape}, expected "
                                   f"{self.n_lights} rows")
        self.rig = rig
        cam_path = self.folder / "cameras.json"
        self.cameras = _load_json(cam_path)
        if not isinstance(self.cameras, list) or len(self.cameras) != self.n_views:
            n = len(self.cameras) if isinstance(self.cameras, list) else "no list of"
            raise ImageFormatError(f"{cam_path}: {n} cameras but capture.json declares {self.n_views} views")
        missing = [
            str(self.path(v, l))
            for v in range(self.n_views)
            for l in range(self.n_lights)
            if not self.path(v, l).is_file()
        ]
        if missing:
            raise ImageFormatError(
                f"{self.folder}: {len(missing)} light image(s) missing for {self.n_lights} lights in the rig, "
                f"first: {missing[0]}"
            )

    def stage_rig(self) -> stage.Rig:
        """``rig.json`` as a ``stage.Rig`` (``stage.rig_from_dict``: either rig
        schema); ValueError naming the file and the field if it is not one."""
        return stage.rig_from_dict(self.rig, str(self.folder / "rig.json"))

    def stage_cameras(self) -> tuple[stage.Camera, ...]:
        """``cameras.json`` as ``stage.Camera`` s (``stage.camera_from_dict``, each
        entry); ValueError naming the file, the camera and the field if an entry
        is not a camera (a free-form dict)."""
        where = self.folder / "cameras.json"
        return tuple(stage.camera_from_dict(c, f"{where}: camera {i}") for i, c in enumerate(self.cameras))

    @property
    def shape(self) -> tuple[int, int, int, int]:
        """``(V, L, P, C)``."""
        return (self.n_views, self.n_lights, self.n_samples, self.n_channels)

    def path(self, view: int, light: int) -> Path:
        """The image of ``view`` under ``light`` (inside the folder, checked)."""
        rel = self._files.format(view=view, light=light)
        return path_inside(self.folder, rel, f"{self.folder / 'capture.json'}: field 'files'",
                           what="the capture folder")

    def read_image(self, view: int, light: int, samples: slice | None = None, dtype=np.float32):
        """One view under one light: ``([P', C] radiance, [P'] valid or None)``,
        ``P'`` the samples selected by ``samples`` (a slice of the flattened image).

        Raises ``ImageFormatError`` naming the file on a missing channel, a
        wrong size, a header from another view/light, NaN or negative radiance.
        """
        path = self.path(view, light)
        chans, header = read_exr_channels(path)
        missing = [c for c in self.channels + (["valid"] if self.has_valid else []) if c not in chans]
        if missing:
            raise ImageFormatError(f"{path}: channel(s) {missing} missing; the file has {sorted(chans)}")
        first = chans[self.channels[0]]
        if first.shape != self.sample_shape:
            raise ImageFormatError(f"{path}: image is {first.shape}, capture.json says {self.sample_shape}")
        if header.get("relight.view", view) != view or header.get("relight.light", light) != light:
            raise ImageFormatError(
                f"{path}: header says view {header.get('relight.view')} light {header.get('relight.light')}, "
                f"but the file is in the place of view {view} light {light}"
            )
        sel = slice(None) if samples is None else samples
        rad = np.stack([chans[c].reshape(-1)[sel] for c in self.channels], axis=-1)
        out_dtype = rad.dtype if dtype is None else dtype
        rad = rad.astype(out_dtype, copy=False)
        check_radiance(rad, path, "radiance")
        valid = chans["valid"].reshape(-1)[sel] > 0.5 if self.has_valid else None
        return rad, valid

    def iter_lights(self, view: int = 0, samples: slice | None = None, dtype=np.float32):
        """Yield ``(light, radiance [P', C], valid [P'] or None)`` for one view, one
        file at a time: memory stays at one image whatever the stack size."""
        for light in range(self.n_lights):
            rad, valid = self.read_image(view, light, samples, dtype)
            yield light, rad, valid

    def _axis(self, sel, n: int, what: str) -> tuple[int, ...]:
        """The indices a selector (None = all, an int, a slice or a sequence of ints) picks, checked."""
        if sel is None:
            return tuple(range(n))
        if isinstance(sel, slice):
            return tuple(range(n)[sel])
        idx = tuple(int(i) for i in np.atleast_1d(np.asarray(sel)))
        for i in idx:
            if not 0 <= i < n:
                raise IndexError(f"{self.folder}: {what} {i} out of range (capture has {n})")
        return idx

    def _load(self, views, lights, samples, dtype):
        """(views, lights, radiance [V', L', P', C], valid [V', L', P'] or None) of a selection."""
        vs = self._axis(views, self.n_views, "view")
        ls = self._axis(lights, self.n_lights, "light")
        if samples is not None and not isinstance(samples, slice):
            raise ValueError(f"{self.folder}: samples must be None or a slice of the flattened image, got {samples!r}")
        n_sel = len(range(*(samples or slice(None)).indices(self.n_samples)))
        radiance = valid = None
        for i, v in enumerate(vs):
            for j, l in enumerate(ls):
                rad, val = self.read_image(v, l, samples, dtype)
                if radiance is None:
                    radiance = np.empty((len(vs), len(ls), n_sel, self.n_channels), rad.dtype)
                    valid = np.empty((len(vs), len(ls), n_sel), bool) if self.has_valid else None
                radiance[i, j] = rad
                if valid is not None:
                    valid[i, j] = val
        if radiance is None:  # nothing selected
            radiance = np.empty((len(vs), len(ls), n_sel, self.n_channels), np.float32 if dtype is None else dtype)
            valid = np.empty(radiance.shape[:3], bool) if self.has_valid else None
        return vs, ls, radiance, valid

    def read(self, views=None, lights=None, samples=None, dtype=np.float32) -> tuple[np.ndarray, np.ndarray]:
        """Radiance and mask of a selection (``relight.io.CaptureSource``'s read).

        Each light image is one file, decoded whole: a selection costs one pass over the files it
        touches, so a stack larger than memory is read a chunk of samples at a time.

        Args:
            views, lights: None (all), an int, a slice or a sequence of ints.
            samples: None or a slice of the flattened image.
            dtype: the radiance's dtype (None keeps the stored one).

        Returns:
            (radiance [V', L', P', C], mask [V', L', P'] bool): the ``valid`` channel, or every
            observation valid where the files have none.
        """
        _, _, radiance, valid = self._load(views, lights, samples, dtype)
        return radiance, np.ones(radiance.shape[:3], bool) if valid is None else valid

    def read_mask(self, views=None, lights=None, samples=None) -> np.ndarray:
        """The mask [V', L', P'] of :meth:`read`'s selection (no file read where the capture has no
        ``valid`` channel: every observation is valid)."""
        if not self.has_valid:
            vs = self._axis(views, self.n_views, "view")
            ls = self._axis(lights, self.n_lights, "light")
            n_sel = len(range(*(samples or slice(None)).indices(self.n_samples)))
            return np.ones((len(vs), len(ls), n_sel), bool)
        return self.read(views, lights, samples, dtype=None)[1]


def open_capture(folder: str | os.PathLike) -> CaptureReader:
    """Open a capture folder lazily (validates the JSON files and that every
    light image exists; reads no pixels)."""
    return CaptureReader(folder)


def read_capture(
    folder: str | os.PathLike,
    views: Sequence[int] | None = None,
    lights: Sequence[int] | None = None,
    dtype=np.float32,
) -> CaptureData:
    """Read a whole capture folder (or the chosen views/lights) into memory.

    Args:
        folder: the capture folder.
        views, lights: the views and lights to read (None = all).
        dtype: the radiance's dtype (None keeps the stored one).

    Returns:
        :class:`CaptureData` (``valid`` None where the files have no valid channel; the rig's
        per-light arrays cut to ``lights``).
    """
    reader = CaptureReader(folder)
    vs, ls, radiance, valid = reader._load(views, lights, None, dtype)
    rig = dict(reader.rig)
    for key in ("directions", "positions", "intensities", "solid_angles"):
        if key in rig and np.ndim(rig[key]) >= 1 and len(rig[key]) == reader.n_lights:
            rig[key] = rig[key][list(ls)]
    return CaptureData(
        radiance=radiance,
        valid=valid,
        rig=rig,
        cameras=[reader.cameras[v] for v in vs],
        metadata=reader.metadata,
        sample_shape=reader.sample_shape,
        lights=ls,
        views=vs,
    )
