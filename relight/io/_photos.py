"""Camera-space photo captures: what a real light stage delivers, one photograph
per camera and light, plus the rig and the camera calibration. The layout
(format ``relight-photos``, version 1) is docs/capture_layout.md; in short::

    folder/capture.json   {"format": "relight-photos", "version": 1,
                           "rig": "rig.json" | {"file": ..., "units": ..., "up": ..., "subset": ...},
                           "cameras": "cameras.json",
                           "images": "{camera}/l{light:03d}.exr",   (pattern, or per view)
                           "encoding": "linear" | "srgb" | "gamma:G",  (PNG only; EXR is linear)
                           "exposure": x, "gain": x, "saturation": s,  (optional defaults)
                           "views": [{"camera": "cam000", "images": ..., "mask": ...,
                                      "exposure": x | [L], "gain": x | [L], "saturation": s}, ...],
                           "metadata": {...}}

Radiance = decoded value / (exposure x gain); a pixel at or above the
saturation level (in stored units, any channel) under a light is invalid under
that light; a mask (PNG or EXR, > 0.5 of full scale inside) marks the pixels
of the subject. Paths in these files are relative to the folder and must stay
inside it. Pixels are read lazily, one camera at a time
(:meth:`PhotoCapture.read_view` / :meth:`PhotoCapture.iter_views`), so a
capture larger than memory is relit camera by camera.
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np

import stage

from ..image._tonemap import srgb_decode
from ._errors import ImageFormatError, check_radiance, file_name, path_inside, path_template
from ._exr import read_exr
from ._json import read_json
from ._png import read_png

__all__ = ["FORMAT", "PhotoCapture", "PhotoView", "is_photo_capture", "read_photo_capture"]

FORMAT = "relight-photos"
VERSION = 1
_DEFAULT_IMAGES = "{camera}/l{light:03d}.exr"
_ENCODINGS = ("linear", "srgb")


@dataclasses.dataclass(frozen=True)
class PhotoView:
    """One camera's photographs, in memory.

    Attributes:
        name: the camera's name (cameras.json).
        camera: its ``stage.Camera``.
        radiance: float32 [L, H, W, C], value / (exposure x gain), 0 where invalid.
        valid: bool [L, H, W]: inside the mask and below saturation.
        mask: bool [H, W] (all True without a mask file).
    """

    name: str
    camera: stage.Camera
    radiance: np.ndarray
    valid: np.ndarray
    mask: np.ndarray


def _err(where, msg) -> ImageFormatError:
    return ImageFormatError(f"{where}: {msg}")


def _inside(folder: Path, rel: object, where: str) -> Path:
    return path_inside(folder, rel, where, what="the capture folder")


def _positive(value, n: int, where: str) -> np.ndarray:
    """A scalar or [n] of positive finite numbers, as float64 [n]."""
    try:
        arr = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise _err(where, f"must be a positive number or a list of {n}, got {value!r}") from None
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise _err(where, f"must be a positive number or a list of {n} positive numbers (one per light), "
                          f"got shape {arr.shape}")
    return arr


def _scale(v: Mapping, n: int, where: str) -> np.ndarray:
    """1 / (exposure x gain) per light [n], float64; refused when it is not a finite float32 (exposure x gain
    below ~3e-39: a unit mistake, not a sensor)."""
    prod = _positive(v.get("exposure", 1.0), n, f"{where}: field 'exposure'") * \
        _positive(v.get("gain", 1.0), n, f"{where}: field 'gain'")
    with np.errstate(divide="ignore", over="ignore"):
        scale = 1.0 / prod
    if not np.all(scale <= np.finfo(np.float32).max):
        raise _err(where, f"fields 'exposure' x 'gain' = {float(prod.min()):.3g} at the smallest: radiance = pixel "
                          "value / (exposure x gain) would overflow float32 (are they in the stated units?)")
    return scale


def _encoding(value, where: str) -> float | str:
    """'linear', 'srgb' or a gamma exponent from 'gamma:G'."""
    if value in _ENCODINGS:
        return value
    if isinstance(value, str) and value.startswith("gamma:"):
        try:
            g = float(value[6:])
        except ValueError:
            g = -1.0
        if np.isfinite(g) and g > 0:
            return g
    raise _err(where, f"must be 'linear', 'srgb' or 'gamma:G' (G > 0), got {value!r}")


def _png_unit(raw: np.ndarray) -> np.ndarray:
    """A PNG's stored values (8 or 16 bit) as float64 fractions of full scale."""
    return raw.astype(np.float64) / (65535.0 if raw.dtype == np.uint16 else 255.0)


def _distortion(camera: stage.Camera) -> dict | None:
    """The camera's OpenCV distortion as {k1, k2, p1, p2, k3}, or None when it has none."""
    d = np.asarray(camera.dist, np.float64)
    return dict(zip(stage.DISTORTION_KEYS, d.tolist(), strict=True)) if np.any(d != 0) else None


def _rig_spec(spec: object, where) -> Mapping:
    """capture.json's ``rig``: a file name, or {"file", "units", "up", "subset"} (strings)."""
    if isinstance(spec, str):
        spec = {"file": spec}
    if not isinstance(spec, Mapping) or "file" not in spec:
        raise _err(where, "field 'rig' must be a file name or {\"file\": ..., \"units\", \"up\", \"subset\"}")
    for key in ("units", "up", "subset"):
        if not isinstance(spec.get(key, ""), str):
            raise _err(where, f"field 'rig': {key!r} must be a string, got {spec[key]!r}")
    return spec


class PhotoCapture:
    """A photo capture folder opened lazily: the JSON files are read and checked,
    and every image file is checked to exist; no pixels are read until asked.

    Attributes:
        folder, rig (``stage.Rig``, in the stage frame, mm), rig_file (Path),
        names (camera names), cameras (``stage.Camera`` per view), distortion
        (per view: OpenCV k1 k2 p1 p2 k3 or None; recorded only: image-based
        relighting works on the photographs as they are and never undistorts),
        n_lights, metadata.
    """

    def __init__(self, folder: str | os.PathLike, rig_units: str | None = None, rig_up: str | None = None,
                 rig_subset: str | None = None):
        self.folder = Path(folder)
        self._warned_unscaled = False
        if not self.folder.is_dir():
            raise FileNotFoundError(f"{self.folder}: no such photo capture folder")
        where = self.folder / "capture.json"
        info = read_json(where, "a photo capture folder needs capture.json")
        if not isinstance(info, Mapping):
            raise _err(where, "must be a JSON object")
        if info.get("format") != FORMAT:
            raise _err(where, f"field 'format' must be {FORMAT!r}, got {info.get('format')!r}")
        version = info.get("version")
        if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= VERSION:
            raise _err(where, f"field 'version' must be an integer 1..{VERSION}, got {version!r}")
        metadata = info.get("metadata") or {}
        if not isinstance(metadata, Mapping):
            raise _err(where, f"field 'metadata' must be a JSON object, got {type(metadata).__name__}")
        self.metadata = dict(metadata)
        rig_spec = _rig_spec(info.get("rig", "rig.json"), where)
        self.rig_file = _inside(self.folder, rig_spec["file"], f"{where}: field 'rig'")
        self.rig = stage.load_rig_file(self.rig_file, units=rig_units or rig_spec.get("units"),
                                       up=rig_up or rig_spec.get("up"),
                                       subset=rig_subset or rig_spec.get("subset"))
        self.n_lights = self.rig.num_lights
        # the cameras
        cam_path = _inside(self.folder, info.get("cameras", "cameras.json"), f"{where}: field 'cameras'")
        self.cameras_file = cam_path
        doc = read_json(cam_path, "camera file")
        entries = doc.get("cameras") if isinstance(doc, Mapping) else doc
        if not isinstance(entries, list) or not entries:
            raise _err(cam_path, "field 'cameras' must be a non-empty list of cameras")
        # A camera's name becomes its folder in what commands write (relight render: OUT/<name>/relit.exr).
        self.names = [file_name(str(e.get("name", f"cam{i:03d}")) if isinstance(e, Mapping) else f"cam{i:03d}",
                                f"{cam_path}: cameras[{i}] field 'name'") for i, e in enumerate(entries)]
        if len(set(self.names)) != len(self.names):
            raise _err(cam_path, f"camera names must be distinct, got {self.names}")
        cams = stage.cameras_from_doc(doc, cam_path)  # the file's convention and units apply to every camera
        self.distortion = [_distortion(c) for c in cams]
        # the views
        defaults = {k: info[k] for k in ("images", "encoding", "exposure", "gain", "saturation", "mask") if k in info}
        views = info.get("views")
        if views is None:
            views = [{"camera": n} for n in self.names]
        if not isinstance(views, list) or not views:
            raise _err(where, "field 'views' must be a non-empty list of {\"camera\": name, ...}")
        self.cameras, self._views = [], []
        order = []
        for i, v in enumerate(views):
            vw = f"{where}: views[{i}]"
            if not isinstance(v, Mapping) or v.get("camera") not in self.names:
                raise _err(vw, f"field 'camera' must name a camera of {cam_path.name} ({self.names})")
            if self.names.index(v["camera"]) in order:
                raise _err(vw, f"camera {v['camera']!r} is listed twice in 'views'")
            order.append(self.names.index(v["camera"]))
            self._views.append(self._parse_view({**defaults, **v}, vw, cams[order[-1]]))
            self.cameras.append(cams[order[-1]])
        self.names = [self.names[k] for k in order]
        self.distortion = [self.distortion[k] for k in order]

    def _parse_view(self, v: Mapping, where: str, cam: stage.Camera) -> dict:
        L = self.n_lights
        pattern = v.get("images", _DEFAULT_IMAGES)
        if isinstance(pattern, list):
            if len(pattern) != L:
                raise _err(where, f"field 'images' lists {len(pattern)} files for {L} lights in the rig")
            rels = pattern
        elif isinstance(pattern, str):
            path_template(pattern, {"camera": str(v["camera"]), "light": 0, "light1": 1}, (),
                          f"{where}: field 'images'")
            try:
                rels = [pattern.format(camera=v["camera"], light=l, light1=l + 1) for l in range(L)]
            except (KeyError, IndexError, ValueError, TypeError, AttributeError) as err:
                raise _err(where, f"field 'images' pattern {pattern!r} is not valid (fields: camera, light, "
                                  f"light1; {err})") from None
        else:
            raise _err(where, "field 'images' must be a file-name pattern or a list of one file per light")
        files = [_inside(self.folder, r, f"{where}: field 'images'") for r in rels]
        suffixes = {f.suffix.lower() for f in files}
        if not suffixes <= {".exr", ".png"}:
            raise _err(where, f"field 'images': files must be .exr or .png, got {sorted(suffixes)}")
        missing = [str(f) for f in files if not f.is_file()]
        if missing:
            raise _err(where, f"{len(missing)} of {L} light images missing, first: {missing[0]}")
        mask = v.get("mask")
        mask = None if mask is None else _inside(self.folder, mask, f"{where}: field 'mask'")
        if mask is not None and not mask.is_file():
            raise _err(where, f"field 'mask': no such file {mask}")
        sat = v.get("saturation")
        if sat is not None and (isinstance(sat, bool) or not isinstance(sat, (int, float)) or not sat > 0):
            raise _err(where, f"field 'saturation' must be a positive number, got {sat!r}")
        return {"files": files, "mask": mask, "saturation": sat,
                "scale_stated": "exposure" in v or "gain" in v,
                "encoding": _encoding(v.get("encoding", "linear"), f"{where}: field 'encoding'"),
                "scale": _scale(v, L, where),
                "size": (cam.height, cam.width)}

    @property
    def n_views(self) -> int:
        return len(self._views)

    def files(self, view: int) -> list[Path]:
        """The image file of each light for ``view``."""
        return list(self._views[view]["files"])

    def _read_image(self, path: Path, encoding, size, saturation) -> tuple[np.ndarray, np.ndarray]:
        """The decoded image [H, W, C] float32, and bool [H, W]: saturated (a
        stored value, PNG scaled to [0, 1] before decoding, at or above
        ``saturation`` in any channel)."""
        if path.suffix.lower() == ".exr":
            img = read_exr(path)
            stored = img
        else:
            raw = read_png(path, shape=size)
            img = _png_unit(raw)
            if raw.shape[-1] in (2, 4):
                img = img[..., :-1]  # drop alpha
            stored = img
            if encoding == "srgb":
                img = np.asarray(srgb_decode(img), np.float64)
            elif not isinstance(encoding, str):
                img = img**encoding
            img = img.astype(np.float32)
        if img.shape[:2] != size:
            raise _err(path, f"image is {img.shape[1]}x{img.shape[0]} but its camera is {size[1]}x{size[0]} "
                             f"(cameras.json)")
        check_radiance(img, path, "pixel values")
        if saturation is None:
            return img, np.zeros(size, bool)
        return img, np.any(stored >= saturation, axis=-1)

    def unscaled_png(self, view: int) -> bool:
        """Whether ``view``'s images are PNGs and capture.json states neither ``exposure`` nor ``gain`` for it:
        their values are then read as fractions of full scale (65535 or 255 = radiance 1), which sensor counts
        are not (docs/capture_layout.md, "From sensor counts to radiance")."""
        v = self._views[view]
        return not v["scale_stated"] and any(f.suffix.lower() == ".png" for f in v["files"])

    def _note_unscaled_counts(self, view: int, first: Path) -> None:
        """Warn, once per capture, that a view's PNGs are read as radiance with no stated scale."""
        if self._warned_unscaled or not self.unscaled_png(view):
            return
        self._warned_unscaled = True
        warnings.warn(f"{self.folder / 'capture.json'}: view {self.names[view]!r} reads PNGs ({first.name}, ...) "
                      "with no 'exposure' or 'gain': radiance = stored value / full scale. If the images are "
                      "sensor counts, state 'gain' (counts per unit radiance / 65535 for 16-bit PNGs; "
                      "docs/capture_layout.md, 'From sensor counts to radiance'), or \"gain\": 1 to confirm "
                      "the values are radiance", UserWarning, stacklevel=3)

    def mask_file(self, view: int) -> Path | None:
        """The mask file of ``view`` (None: no mask, every pixel is the subject's)."""
        return self._views[view]["mask"]

    def read_mask(self, view: int) -> np.ndarray:
        """bool [H, W]: the view's mask (> half of full scale in its first
        channel), all True without one."""
        v = self._views[view]
        if v["mask"] is None:
            return np.ones(v["size"], bool)
        path = v["mask"]
        if path.suffix.lower() == ".exr":
            m = read_exr(path)[..., 0] > 0.5
        elif path.suffix.lower() == ".png":
            m = _png_unit(read_png(path, shape=v["size"])[..., 0]) > 0.5
        else:
            raise _err(path, "a mask must be .png or .exr")
        if m.shape != v["size"]:
            raise _err(path, f"mask is {m.shape[1]}x{m.shape[0]} but its camera is {v['size'][1]}x{v['size'][0]}")
        return m

    def read_view(self, view: int, lights: Sequence[int] | None = None) -> PhotoView:
        """One camera's photographs (or those of ``lights``) as a :class:`PhotoView`:
        [L, H, W, C] radiance, float32, 0 where invalid."""
        if not 0 <= view < self.n_views:
            raise IndexError(f"{self.folder}: view {view} out of range (capture has {self.n_views})")
        v = self._views[view]
        ls = range(self.n_lights) if lights is None else [int(l) for l in lights]
        mask = self.read_mask(view)
        rad = valid = None
        for j, l in enumerate(ls):
            img, saturated = self._read_image(v["files"][l], v["encoding"], v["size"], v["saturation"])
            if j == 0:
                self._note_unscaled_counts(view, v["files"][l])
            if rad is None:
                rad = np.empty((len(ls), *img.shape), np.float32)
                valid = np.empty((len(ls), *img.shape[:2]), bool)
            elif img.shape != rad.shape[1:]:
                raise _err(v["files"][l], f"has {img.shape[-1]} channels, the view's first image "
                                          f"{rad.shape[-1]}")
            ok = mask & ~saturated
            valid[j] = ok
            rad[j] = np.where(ok[..., None], img * np.float32(v["scale"][l]), np.float32(0))
            # A tiny exposure x gain (wrong units, counts taken for a fraction of full scale) makes radiance
            # beyond what the downstream sums hold: refused naming the file, not rendered as Inf and NaN.
            check_radiance(rad[j], v["files"][l], "radiance (the pixel values / (exposure x gain))")
        return PhotoView(self.names[view], self.cameras[view], rad, valid, mask)

    def iter_views(self) -> Iterator[PhotoView]:
        """Yield each camera's :class:`PhotoView` in turn (one camera in memory)."""
        for i in range(self.n_views):
            yield self.read_view(i)

    def __len__(self) -> int:
        return self.n_views

    def __iter__(self) -> Iterator[PhotoView]:
        return self.iter_views()


def is_photo_capture(folder: str | os.PathLike) -> bool:
    """Whether ``folder/capture.json`` says format ``relight-photos``."""
    p = Path(folder) / "capture.json"
    if not p.is_file():
        return False
    try:
        info = read_json(p)
    except ValueError:
        return False
    return isinstance(info, Mapping) and info.get("format") == FORMAT


def read_photo_capture(folder: str | os.PathLike, rig_units: str | None = None, rig_up: str | None = None,
                       rig_subset: str | None = None) -> PhotoCapture:
    """Open a photo capture folder (docs/capture_layout.md) lazily.

    ``rig_units`` / ``rig_up`` / ``rig_subset`` state (or override) the rig
    file's units ("mm" | "cm" | "m" | "directions"), up axis ("+y", "-y", ...)
    and named light subset (``stage.load_rig_file``); a .npy rig needs the
    first two. Raises FileNotFoundError, or ImageFormatError / ValueError
    naming the file and the field.
    """
    return PhotoCapture(folder, rig_units, rig_up, rig_subset)
