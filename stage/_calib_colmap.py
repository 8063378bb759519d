"""COLMAP sparse models (``cameras.txt`` + ``images.txt``, or ``cameras.bin`` + ``images.bin``) as cameras.

COLMAP's camera models that are a pinhole with OpenCV's distortion map exactly onto a :class:`~stage.Camera`:

| model | params | Camera |
| --- | --- | --- |
| SIMPLE_PINHOLE | f, cx, cy | fx = fy = f |
| PINHOLE | fx, fy, cx, cy | |
| SIMPLE_RADIAL | f, cx, cy, k | dist = (k, 0, 0, 0, 0) |
| RADIAL | f, cx, cy, k1, k2 | dist = (k1, k2, 0, 0, 0) |
| OPENCV | fx, fy, cx, cy, k1, k2, p1, p2 | dist = (k1, k2, p1, p2, 0) |

Every other model (OPENCV_FISHEYE, FULL_OPENCV, FOV, the fisheye and thin-prism models, ...) is refused.
COLMAP's pixel convention is the Camera's (the top-left pixel's centre at (0.5, 0.5)), so K is taken as
written. An image's pose is world to camera: a Hamilton quaternion (QW, QX, QY, QZ) and a translation
(TX, TY, TZ) in the model's arbitrary units, x right, y down, z forward, as the Camera's.

References: COLMAP's documentation, "Output format" (the text and binary layouts) and "Camera models";
``src/colmap/sensor/models.h`` (the models' parameter order) and ``scripts/python/read_write_model.py``.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ._calib_common import CENTRES_AT_HALVES, build_camera, mm_per_unit_value, quaternion_to_matrix
from ._camera import Camera
from ._files import existing_path

# COLMAP's model ids and names (models.h), every one, so a refusal can name the model; the supported ones with
# the number of their parameters.
_MODEL_NAMES = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "OPENCV_FISHEYE", "FULL_OPENCV",
                "FOV", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "THIN_PRISM_FISHEYE", "RAD_TAN_THIN_PRISM_FISHEYE")
_SUPPORTED = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5, "OPENCV": 8}

# Fixed-size parts of the binary records (little-endian, read_write_model.py): a camera's id, model id, width
# and height; an image's id, qvec, tvec and camera id; one 2D point (x, y, point3D_id).
_CAMERA_HEAD = struct.Struct("<iiQQ")
_IMAGE_HEAD = struct.Struct("<i4d3di")
_POINT2D_BYTES = 24


def _intrinsics(model: str, params: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """K [3, 3] and OpenCV's five distortion coefficients of a supported model's parameters."""
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = params[0]
        cx, cy = params[1], params[2]
        radial = params[3:]
    else:  # PINHOLE, OPENCV: fx, fy, cx, cy first
        fx, fy, cx, cy = params[:4]
        radial = params[4:]
    dist = np.zeros(5)
    dist[: len(radial)] = radial  # (k), (k1, k2) or (k1, k2, p1, p2): OpenCV's order
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), dist


def _model_name(model: int | str) -> str:
    """COLMAP's name of a model given by id (binary) or name (text)."""
    if isinstance(model, str):
        return model
    return _MODEL_NAMES[model] if 0 <= model < len(_MODEL_NAMES) else f"model id {model}"


def _check_model(path: Path, camera_id: int, model: str, n_params: int | None) -> None:
    """Refuse a model that is not a pinhole with OpenCV's distortion, or the wrong number of parameters."""
    if model not in _SUPPORTED:
        raise ValueError(f"{path}: camera {camera_id}: model {model} is not supported (supported: "
                         f"{', '.join(_SUPPORTED)}: a pinhole with OpenCV's k1, k2, p1, p2); undistort the images "
                         "with COLMAP's image_undistorter, or calibrate with one of these models")
    if n_params is not None and n_params != _SUPPORTED[model]:
        raise ValueError(f"{path}: camera {camera_id}: field 'PARAMS': model {model} takes {_SUPPORTED[model]} "
                         f"parameters, got {n_params}")


def _numbers(path: Path, lineno: int, field: str, tokens: list[str], kind=float) -> list:
    """``tokens`` as numbers, or a ValueError naming the file, the line and the field."""
    try:
        return [kind(x) for x in tokens]
    except ValueError:
        raise ValueError(f"{path}:{lineno}: field {field!r}: expected numbers, got {' '.join(tokens)!r}") from None


def _read_cameras_text(path: Path) -> dict[int, tuple[str, int, int, list[float]]]:
    """cameras.txt: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]`` per line, '#' comments."""
    out = {}
    for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
        elems = line.split()
        if not elems or elems[0].startswith("#"):
            continue
        if len(elems) < 4:
            raise ValueError(f"{path}:{lineno}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got {line!r}")
        (camera_id,) = _numbers(path, lineno, "CAMERA_ID", elems[:1], int)
        width, height = _numbers(path, lineno, "WIDTH/HEIGHT", elems[2:4], int)
        params = _numbers(path, lineno, "PARAMS", elems[4:])
        _check_model(path, camera_id, elems[1], len(params))
        if camera_id in out:
            raise ValueError(f"{path}:{lineno}: camera {camera_id} is listed twice")
        out[camera_id] = (elems[1], width, height, params)
    return out


def _read_images_text(path: Path) -> list[tuple[str, np.ndarray, np.ndarray, int]]:
    """images.txt: per image ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME``, then one line of 2D points
    (skipped, empty for an image without points), as COLMAP's reader: the line after an image line is always
    its points."""
    out = []
    lines = path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        line, lineno = lines[i], i + 1
        i += 1
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        elems = line.split(maxsplit=9)
        if len(elems) < 10:
            raise ValueError(f"{path}:{lineno}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got "
                             f"{line!r}")
        qt = _numbers(path, lineno, "QW QX QY QZ TX TY TZ", elems[1:8])
        (camera_id,) = _numbers(path, lineno, "CAMERA_ID", elems[8:9], int)
        out.append((elems[9].strip(), np.array(qt[:4]), np.array(qt[4:]), camera_id))
        i += 1  # the POINTS2D line
    return out


class _Bytes:
    """A bounds-checked little-endian reader over a binary model file: every short read names the file, the
    record and the field."""

    def __init__(self, path: Path):
        self.path, self.data, self.at = path, path.read_bytes(), 0

    def take(self, fmt: struct.Struct, what: str) -> tuple:
        if self.at + fmt.size > len(self.data):
            raise ValueError(f"{self.path}: truncated at byte {self.at} reading {what}")
        out = fmt.unpack_from(self.data, self.at)
        self.at += fmt.size
        return out

    def skip(self, n: int, what: str) -> None:
        if n < 0 or self.at + n > len(self.data):
            raise ValueError(f"{self.path}: truncated at byte {self.at} reading {what}")
        self.at += n

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.at)
        if end < 0:
            raise ValueError(f"{self.path}: truncated at byte {self.at} reading {what} (no NUL terminator)")
        try:
            out = self.data[self.at:end].decode("utf-8")
        except UnicodeDecodeError:
            raise ValueError(f"{self.path}: {what} at byte {self.at} is not UTF-8") from None
        self.at = end + 1
        return out

    def count(self, record_bytes: int, what: str) -> int:
        """A record count, checked against the bytes left (each record at least ``record_bytes``)."""
        (n,) = self.take(struct.Struct("<Q"), f"the number of {what}")
        if n * record_bytes > len(self.data) - self.at:
            raise ValueError(f"{self.path}: declares {n} {what}, more than its {len(self.data)} bytes hold")
        return n

    def done(self) -> None:
        if self.at != len(self.data):
            raise ValueError(f"{self.path}: {len(self.data) - self.at} bytes after the last record")


def _read_cameras_binary(path: Path) -> dict[int, tuple[str, int, int, list[float]]]:
    """cameras.bin: uint64 count; per camera int32 id, int32 model id, uint64 width, uint64 height,
    float64 params[n(model)]."""
    f = _Bytes(path)
    out = {}
    for k in range(f.count(_CAMERA_HEAD.size, "cameras")):
        camera_id, model_id, width, height = f.take(_CAMERA_HEAD, f"camera record {k}")
        model = _model_name(model_id)
        _check_model(path, camera_id, model, None)
        n = _SUPPORTED[model]
        params = list(f.take(struct.Struct(f"<{n}d"), f"camera {camera_id}'s PARAMS"))
        if camera_id in out:
            raise ValueError(f"{path}: camera {camera_id} is listed twice")
        out[camera_id] = (model, width, height, params)
    f.done()
    return out


def _read_images_binary(path: Path) -> list[tuple[str, np.ndarray, np.ndarray, int]]:
    """images.bin: uint64 count; per image int32 id, float64 qvec[4], float64 tvec[3], int32 camera id,
    NUL-terminated name, uint64 num_points2D, num_points2D x (float64 x, float64 y, int64 point3D_id)."""
    f = _Bytes(path)
    out = []
    for k in range(f.count(_IMAGE_HEAD.size + 1 + 8, "images")):
        head = f.take(_IMAGE_HEAD, f"image record {k}")
        name = f.name(f"image {head[0]}'s NAME")
        (n_points,) = f.take(struct.Struct("<Q"), f"image {name!r}'s num_points2D")
        f.skip(n_points * _POINT2D_BYTES, f"image {name!r}'s POINTS2D")
        out.append((name, np.array(head[1:5]), np.array(head[5:8]), head[8]))
    f.done()
    return out


def _model_files(folder: Path) -> tuple[Path, Path, bool]:
    """The cameras and images files of a model folder and whether they are text: the text pair when both text
    files are there (text wins over binary: it is what a person edits and COLMAP's model_converter writes),
    else the binary pair."""
    for ext, text in ((".txt", True), (".bin", False)):
        cams, imgs = folder / f"cameras{ext}", folder / f"images{ext}"
        if cams.is_file() and imgs.is_file():
            return cams, imgs, text
    present = sorted(p.name for p in folder.iterdir() if p.name.startswith(("cameras.", "images.")))
    raise FileNotFoundError(f"{folder}: no COLMAP model here (needs cameras.txt + images.txt or cameras.bin + "
                            f"images.bin; found {', '.join(present) or 'neither'})")


def read_colmap(path, mm_per_unit: float | str) -> dict[str, Camera]:
    """The cameras of a COLMAP sparse model folder (e.g. ``sparse/0``), one per registered image.

    Reads ``cameras.txt`` + ``images.txt`` when both are there, else ``cameras.bin`` + ``images.bin``
    (COLMAP's own output; text is preferred when a folder holds both pairs). The models SIMPLE_PINHOLE,
    PINHOLE, SIMPLE_RADIAL, RADIAL and OPENCV map exactly onto a Camera (K and OpenCV's distortion, module
    docstring); COLMAP's pixel convention is the Camera's, so K is not shifted. The pose is world to camera
    (a Hamilton quaternion QW QX QY QZ and TX TY TZ); the translation is scaled by ``mm_per_unit``.

    Args:
        path: the model folder.
        mm_per_unit: millimetres per unit of the model (COLMAP's units are arbitrary: the scale of the scene
            at reconstruction, unless the model was aligned to known positions), a positive finite number or
            "mm", "cm", "m".

    Returns:
        ``{NAME: Camera}`` in the order of the images in the images file, keyed by the image NAME as COLMAP
        stores it (the image's path relative to the image folder, e.g. ``"cam000.png"``).

    Raises:
        FileNotFoundError naming the folder when it, or a pair of model files, is missing. ValueError naming
        the file (and line, camera or image) and the field for a bad ``mm_per_unit``, an unsupported camera
        model (named with its camera id), a malformed or truncated line or record, an image whose camera is
        not in the cameras file, a name listed twice, or a camera that ``stage.camera_from_dict`` refuses.

    References:
        COLMAP's documentation, "Output format" and "Camera models"; ``scripts/python/read_write_model.py``.
    """
    mm = mm_per_unit_value(mm_per_unit)
    folder = existing_path(path, "COLMAP model folder", folder=True)
    cams_path, imgs_path, text = _model_files(folder)
    cameras = _read_cameras_text(cams_path) if text else _read_cameras_binary(cams_path)
    images = _read_images_text(imgs_path) if text else _read_images_binary(imgs_path)
    if not images:
        raise ValueError(f"{imgs_path}: no images (no registered camera poses)")
    out: dict[str, Camera] = {}
    for name, qvec, tvec, camera_id in images:
        where = f"{imgs_path}: image {name!r}"
        if name in out:
            raise ValueError(f"{where} is listed twice")
        if camera_id not in cameras:
            raise ValueError(f"{where}: field 'CAMERA_ID': camera {camera_id} is not in {cams_path}")
        model, width, height, params = cameras[camera_id]
        K, dist = _intrinsics(model, params)
        R = quaternion_to_matrix(qvec, f"{where}: field 'QW QX QY QZ'")
        out[name] = build_camera(f"{cams_path}: camera {camera_id} ({where})", K, R, tvec, width, height, dist,
                                 CENTRES_AT_HALVES, mm)
    return out
