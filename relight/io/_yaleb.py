"""Real faces under a 64-strobe dome: the Extended Yale Face Database B, cropped set
(Georghiades, Belhumeur & Kriegman, TPAMI 2001, "From Few to Many"; Lee, Ho & Kriegman,
TPAMI 2005, "Acquiring Linear Subspaces for Face Recognition under Variable Lighting"):

    folder/yaleBNN_P00A+035E+40.pgm ...   one 8-bit binary PGM (P5) per strobe, frontal pose
    folder/yaleBNN_P00.info               optional: the frame list (the ambient frame is skipped)

``A+035E+40`` is the strobe's azimuth and elevation in degrees relative to the camera axis.
Elevation > 0 is above the camera. Azimuth > 0 is the subject's right, which is the left of the
image: read on the images, frames with azimuth > 0 light the image's left half (the check is in
the tests). So, in the camera frame of :mod:`relight.io` (x right in the image, y up, z toward the
camera), the direction toward the strobe is (-sin A cos E, sin E, cos A cos E).

The camera (a Sony XC-75) is documented as linear; the values are used as stored, divided by the
PGM's maximum value. The strobes are nominally equal but uncalibrated, so their common intensity is a
choice of units: it is pi (:data:`YALEB_INTENSITY`), at which a white Lambertian surface facing a strobe
reads full scale. Albedos then come out in their physical range: at intensity 1 a face reading half
scale would need albedo pi / 2, beyond the fit's bound of 1, and every bright texel would clip there.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ._diligent import DiligentData
from ._errors import ImageFormatError

__all__ = ["YALEB_DARK", "YALEB_INTENSITY", "is_yaleb_folder", "read_pgm", "read_yaleb", "yaleb_direction"]

# A frame name: subject, pose 00, azimuth and elevation with explicit signs.
_FRAME = re.compile(r"^(?P<subject>yaleB\d+)_P00A(?P<az>[+-]\d{3})E(?P<el>[+-]\d{2})\.pgm$")
# The database's frames are 168 x 192; a header larger than this is not a face crop but a hostile file.
_MAX_PGM_PIXELS = 4096 * 4096
# Below 1% of full scale a value is taken as no light: the database's shadowed pixels sit at 0-2 of 255.
YALEB_DARK = 0.01
# The strobes' common intensity (see the module docstring): full scale = a white Lambertian surface at normal incidence.
YALEB_INTENSITY = float(np.pi)


def read_pgm(path: str | os.PathLike) -> tuple[np.ndarray, int]:
    """Read one binary PGM (P5, Netpbm) image; 16-bit samples are big-endian in the file.

    Args:
        path: the file.

    Returns:
        ``(image, maxval)``: the samples, uint8 or uint16 [H, W], and the header's maximum value.

    Raises ImageFormatError naming the file: not P5, a bad header, a size over 4096^2, or fewer
    bytes than the header declares.
    """
    path = Path(path)
    data = path.read_bytes()
    if data[:2] != b"P5":
        raise ImageFormatError(f"{path}: not a binary PGM (expected the magic 'P5', got {data[:2]!r})")
    fields, pos = [], 2
    while len(fields) < 3:
        while pos < len(data) and data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":  # a comment runs to the end of its line
            end = data.find(b"\n", pos)
            pos = len(data) if end < 0 else end + 1
            continue
        start = pos
        while pos < len(data) and data[pos:pos + 1].isdigit():
            pos += 1
        if start == pos:
            raise ImageFormatError(f"{path}: bad PGM header (expected width, height and maximum value)")
        fields.append(int(data[start:pos]))
    pos += 1  # exactly one whitespace byte ends the header
    w, h, maxval = fields
    if not (0 < w and 0 < h and w * h <= _MAX_PGM_PIXELS and 0 < maxval < 65536):
        raise ImageFormatError(f"{path}: PGM size {w} x {h} or maximum value {maxval} out of range "
                               f"(at most {_MAX_PGM_PIXELS} pixels, maximum value 1..65535)")
    dtype = np.dtype(">u2") if maxval > 255 else np.dtype(np.uint8)
    need = w * h * dtype.itemsize
    if len(data) - pos < need:
        raise ImageFormatError(f"{path}: {len(data) - pos} bytes of pixels, the header declares {need}")
    return np.frombuffer(data, dtype, w * h, pos).reshape(h, w).astype(dtype.newbyteorder("=")), maxval


def yaleb_direction(azimuth_deg, elevation_deg) -> np.ndarray:
    """Unit directions toward Yale B strobes, [..., 3] in the camera frame (x right in the image, y up,
    z toward the camera), from the file names' azimuth (> 0: the subject's right, the image's left) and
    elevation (> 0: up), in degrees."""
    a, e = np.radians(np.asarray(azimuth_deg, float)), np.radians(np.asarray(elevation_deg, float))
    return np.stack([-np.sin(a) * np.cos(e), np.sin(e), np.cos(a) * np.cos(e)], -1)


def _frames(folder: Path) -> list[tuple[str, float, float]]:
    """(file name, azimuth, elevation) of every strobe frame in the folder, sorted by name."""
    out = []
    for p in sorted(folder.iterdir()):
        m = _FRAME.match(p.name)
        if m and p.is_file():
            out.append((p.name, float(m["az"]), float(m["el"])))
    return out


def is_yaleb_folder(folder: str | os.PathLike) -> bool:
    """A folder of Yale B frontal-pose strobe frames (``yaleBNN_P00A<az>E<el>.pgm``)."""
    folder = Path(folder)
    return folder.is_dir() and not (folder / "capture.json").exists() and bool(_frames(folder))


def read_yaleb(folder: str | os.PathLike, *, face_threshold: float = 0.05) -> DiligentData:
    """Read one Yale B subject's frontal-pose frames into the DiLiGenT form
    (:func:`relight.io.diligent_capture` then turns it into a capture for ``relight.fit``).

    Args:
        folder: the subject's folder (e.g. ``.../yaleb/yaleB28``).
        face_threshold: the mask keeps the pixels whose median over the frames is at least this
            fraction of full scale: the face, lit by about half the strobes, and not the dark
            background (which no strobe lights).

    Returns:
        ``DiligentData``: images ``[L, H, W, 3]`` float32 (the grey value / the PGM maximum, in the three
        channels), light directions from :func:`yaleb_direction`, intensities :data:`YALEB_INTENSITY`,
        the mask, no normals, the file names (sorted).

    Raises ImageFormatError naming the file: frames of different sizes or bit depths, a frame that
    cannot be read; FileNotFoundError when the folder holds no strobe frame.
    """
    if not 0.0 <= face_threshold < 1.0:
        raise ValueError(f"face_threshold must be in [0, 1), got {face_threshold}")
    folder = Path(folder)
    frames = _frames(folder) if folder.is_dir() else []
    if not frames:
        raise FileNotFoundError(f"{folder}: no Yale B frames (expected yaleBNN_P00A+035E+40.pgm, ...)")
    images, scale = None, None
    for k, (name, _, _) in enumerate(frames):
        img, maxval = read_pgm(folder / name)
        if images is None:
            images, scale = np.empty((len(frames), *img.shape), np.float32), maxval
        elif img.shape != images.shape[1:] or maxval != scale:
            raise ImageFormatError(f"{folder / name}: size {img.shape} / maximum {maxval} differ from the first "
                                   f"frame's {images.shape[1:]} / {scale}")
        images[k] = img.astype(np.float32) / np.float32(scale)
    mask = np.median(images, axis=0) >= face_threshold
    dirs = yaleb_direction([f[1] for f in frames], [f[2] for f in frames]).astype(np.float32)
    return DiligentData(images=np.repeat(images[..., None], 3, axis=-1), light_directions=dirs,
                        light_intensities=np.full((len(frames), 3), YALEB_INTENSITY, np.float32), mask=mask,
                        normals_gt=None, filenames=tuple(f[0] for f in frames))
