"""Writing photo captures (the ``relight-photos`` layout of :mod:`relight.io._photos`): the streaming writer that
takes a light chunk of one camera at a time, and :func:`write_photo_capture`, which writes stacks held in memory
through it."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

import stage

from ..image._tonemap import srgb_encode, to_uint16
from ._capture import _atomic_folder
from ._errors import file_name
from ._exr import write_exr
from ._json import write_json
from ._photos import FORMAT, VERSION, _encoding, is_photo_capture
from ._png import write_png

__all__ = ["PhotoCaptureWriter", "write_photo_capture"]


class PhotoCaptureWriter:
    """A photo capture folder written a light chunk of one camera at a time (a context manager).

    ``write(view, lights, images)`` writes the photographs ``images`` [nL, H, W, C] (the values as stored:
    exposure x gain x radiance) of camera ``view`` under the rig's lights ``lights`` (a slice) as one file each;
    ``write_mask(view, mask)`` the camera's mask. Everything goes into a hidden sibling folder; ``close()``
    (leaving the ``with`` block normally) checks that every (camera, light) photograph was written, writes
    capture.json, rig.json and cameras.json and swaps the folder into place; leaving it by an exception leaves
    ``folder`` as it was. Memory is one chunk: a capture larger than memory is written as it is simulated
    (``stage.iter_images``).

    Args:
        folder: the photo capture folder; new, empty, or an earlier photo capture (replaced).
        rig: the L lights (``stage.Rig``, mm).
        cameras: the V ``stage.Camera`` s.
        names: the cameras' names (default cam000, cam001, ...): also the folders of their photographs.
        fmt: "exr" (float, or ``half``) or "png" (16-bit, values clipped to [0, 1] and encoded per ``encoding``).
        encoding: "linear", "srgb" or "gamma:G" (PNG only; EXR is linear).
        half: EXR as half floats.
        exposure: per view, a scalar or [L] (recorded: radiance = value / (exposure x gain)).
        gain: per view, a scalar or [L].
        saturation: the stored value at and above which a pixel is invalid under its light (recorded).
        metadata: JSON-able dict (capture.json's metadata).

    Raises:
        FileExistsError: ``folder`` exists and is neither empty nor a photo capture.
        ValueError: on mismatched counts, an unknown ``fmt`` or ``encoding``, or (``close``) a photograph never
            written.
    """

    def __init__(self, folder: str | os.PathLike, rig: stage.Rig, cameras: Sequence[stage.Camera],
                 names: Sequence[str] | None = None, *, fmt: str = "exr", encoding: str = "linear",
                 half: bool = False, exposure=None, gain=None, saturation: float | None = None,
                 metadata: Mapping | None = None):
        self.folder = Path(folder)
        f = self.folder
        if f.exists() and (not f.is_dir() or (any(f.iterdir()) and not is_photo_capture(f))):
            raise FileExistsError(f"{f}: exists and is neither empty nor a photo capture; refusing to replace it")
        self.cameras = tuple(cameras)
        self.names = ([f"cam{i:03d}" for i in range(len(self.cameras))] if names is None else
                      [file_name(str(n), f"write_photo_capture: names[{i}]", error=ValueError)
                       for i, n in enumerate(names)])
        if len(self.names) != len(self.cameras):
            raise ValueError(f"{f}: {len(self.cameras)} cameras, {len(self.names)} names")
        if fmt not in ("exr", "png"):
            raise ValueError(f"{f}: fmt must be 'exr' or 'png', got {fmt!r}")
        self.rig, self.fmt, self.encoding, self.half = rig, fmt, encoding, half
        self._enc = _encoding(encoding, "encoding")
        self.exposure, self.gain, self.saturation, self.metadata = exposure, gain, saturation, metadata
        self._written = np.zeros((len(self.cameras), rig.num_lights), bool)
        self._masks = [False] * len(self.cameras)
        self._stack = contextlib.ExitStack()
        if f.is_dir() and not any(f.iterdir()):
            f.rmdir()  # an empty folder is replaced by the capture
        self.tmp = self._stack.enter_context(_atomic_folder(f))
        for name in self.names:
            (self.tmp / name).mkdir()

    def __enter__(self) -> PhotoCaptureWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self._stack.__exit__(exc_type, exc, tb)

    def write(self, view: int, lights: slice, images) -> None:
        """Write camera ``view``'s photographs ``images`` [nL, H, W, C] under the lights ``lights``, one file each."""
        images = np.asarray(images, np.float32)
        cam = self.cameras[view]
        L = self.rig.num_lights
        ids = range(*lights.indices(L))
        if images.ndim != 4 or images.shape[0] != len(ids) or images.shape[1:3] != (cam.height, cam.width):
            raise ValueError(f"{self.folder}: camera {view}'s photographs under lights {lights.start}..{lights.stop} "
                             f"must be [{len(ids)}, {cam.height}, {cam.width}, C], got {images.shape}")
        for l, img in zip(ids, images, strict=True):
            path = self.tmp / self.names[view] / f"l{l:03d}.{self.fmt}"
            if self.fmt == "exr":
                write_exr(path, img, half=self.half)
            else:
                x = np.clip(img.astype(np.float64), 0.0, 1.0)
                if self._enc == "srgb":
                    x = np.asarray(srgb_encode(x), np.float64)
                elif not isinstance(self._enc, str):
                    x = x ** (1.0 / self._enc)
                write_png(path, to_uint16(x))
            self._written[view, l] = True

    def write_mask(self, view: int, mask) -> None:
        """Write camera ``view``'s mask, bool [H, W] (the pixels of the subject), as an 8-bit PNG."""
        write_png(self.tmp / self.names[view] / "mask.png", np.where(np.asarray(mask, bool), 255, 0).astype(np.uint8))
        self._masks[view] = True

    def close(self) -> Path:
        """Write capture.json, rig.json and cameras.json and swap the folder into place; returns its path."""
        with self._stack:  # swapped into place on success; removed on any error
            missing = np.argwhere(~self._written)
            if len(missing):
                v, l = missing[0]
                raise ValueError(f"{self.folder}: {len(missing)} photograph(s) never written, the first camera {v} "
                                 f"({self.names[v]}) under light {l}")
            write_json(self.tmp / "rig.json", {**stage.rig_to_dict(self.rig), "units": "mm"})
            stage.save_cameras(self.tmp / "cameras.json", self.cameras, self.names)
            views = []
            for v, name in enumerate(self.names):
                entry = {"camera": name, "images": f"{name}/l{{light:03d}}.{self.fmt}"}
                if self._masks[v]:
                    entry["mask"] = f"{name}/mask.png"
                for key, val in (("exposure", self.exposure), ("gain", self.gain)):
                    if val is not None:
                        entry[key] = np.asarray(val[v], np.float64).tolist()
                if self.fmt == "png" and self.gain is None and self.exposure is None:
                    entry["gain"] = 1.0  # the values written are radiance: said, so a reader need not warn
                views.append(entry)
            doc = {"format": FORMAT, "version": VERSION, "rig": "rig.json", "cameras": "cameras.json",
                   "encoding": self.encoding if self.fmt == "png" else "linear", "views": views,
                   "metadata": dict(self.metadata or {})}
            if self.saturation is not None:
                doc["saturation"] = float(self.saturation)
            write_json(self.tmp / "capture.json", doc)
        return self.folder


def write_photo_capture(folder: str | os.PathLike, images: Sequence[np.ndarray], rig: stage.Rig,
                        cameras: Sequence[stage.Camera], names: Sequence[str] | None = None, fmt: str = "exr",
                        encoding: str = "linear", half: bool = False, exposure=None, gain=None,
                        masks: Sequence[np.ndarray | None] | None = None, saturation: float | None = None,
                        metadata: Mapping | None = None) -> Path:
    """Write a photo capture folder: ``images[v]`` [L, H, W, C] float, the values
    as stored (exposure x gain x radiance), per camera; ``fmt`` "exr" (float or
    ``half``) or "png" (16-bit, values in [0, 1], sRGB- or gamma-encoded per
    ``encoding``). ``exposure`` / ``gain``: per view, a scalar or [L]. The
    folder must be new, empty or an earlier photo capture; the whole folder is
    written under a temporary name and swapped into place when complete
    (:class:`PhotoCaptureWriter`, which writes captures larger than memory chunk by chunk)."""
    if len(images) != len(tuple(cameras)):
        raise ValueError(f"{folder}: {len(images)} image stacks, {len(tuple(cameras))} cameras")
    with PhotoCaptureWriter(folder, rig, cameras, names, fmt=fmt, encoding=encoding, half=half, exposure=exposure,
                            gain=gain, saturation=saturation, metadata=metadata) as w:
        for v, stack in enumerate(images):
            stack = np.asarray(stack, np.float32)
            if stack.ndim != 4 or stack.shape[0] != rig.num_lights:
                raise ValueError(f"{folder}: images[{v}] must be [L={rig.num_lights}, H, W, C], got {stack.shape}")
            w.write(v, slice(0, rig.num_lights), stack)
            if masks is not None and masks[v] is not None:
                w.write_mask(v, masks[v])
    return Path(folder)
