"""8/16-bit texture images (JPEG, PNG, TIFF) to linear float, and the head
scan's own skin textures bundled in ``relight/data`` (CC-BY 3.0, Infinite
Realities / Lee Perry-Smith; see relight/data/ATTRIBUTION.md)."""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

import numpy as np

from ..image import srgb_decode
from ._errors import ImageFormatError, check_image_size, existing_file
from ._png import read_png

__all__ = ["HEAD_SKIN_FILES", "head_skin_textures", "read_texture"]

# The bundled maps (relight/data), 1024 x 1024 8-bit JPEGs in the head mesh's TEXCOORD_0 layout.
HEAD_SKIN_FILES = {
    "albedo": "lee_perry_smith_albedo.jpg",  # Map-COL.jpg: diffuse colour, sRGB
    "specular": "lee_perry_smith_specular.jpg",  # Map-SPEC.jpg: grey specular intensity (data)
    "normal": "lee_perry_smith_normal.jpg",  # Infinite-Level_02_Tangent_SmoothUV.jpg: tangent-space normals
}

# Pillow modes with an integer sample scale: mode -> full-scale value. "I" (32-bit int) is how Pillow opens
# 16-bit greyscale TIFFs on some versions; its values are 16-bit there, so it shares I;16's scale.
_SCALE = {"L": 255.0, "LA": 255.0, "RGB": 255.0, "RGBA": 255.0, "I;16": 65535.0, "I;16B": 65535.0,
          "I;16L": 65535.0, "I": 65535.0}


def read_texture(path: str | os.PathLike, *, srgb: bool = True) -> np.ndarray:
    """Read an 8- or 16-bit JPEG / PNG / TIFF as float32 ``[H, W, C]`` in [0, 1]
    (C = 1 grey, 2 grey + alpha, 3 RGB, 4 RGBA), rows as stored (row 0 = top).

    ``srgb=True`` decodes the colour channels with the IEC 61966-2-1 transfer
    (:func:`relight.image.srgb_decode`) to linear; alpha is never decoded. Use
    ``srgb=False`` for data maps (normal, roughness, masks). PNGs go through
    :func:`read_png` so 16 bits survive (Pillow would reduce them to 8);
    other formats through Pillow (palette and CMYK images are converted to
    RGB(A); a float ``F``-mode TIFF is returned as stored, never decoded).
    Raises :class:`ImageFormatError` (a ValueError) naming the file when it is
    missing, not a readable image, or declares more than ``MAX_IMAGE_PIXELS``
    (checked from the header, before decoding).
    """
    path = Path(path)
    existing_file(path, "texture file", missing=ImageFormatError)
    with open(path, "rb") as fh:
        is_png = fh.read(8) == b"\x89PNG\r\n\x1a\n"
    if is_png:
        raw = read_png(path)
        values = raw.astype(np.float64) / (65535.0 if raw.dtype == np.uint16 else 255.0)
        linear_stored = False
    else:
        values, linear_stored = _read_pillow(path)
    if values.ndim != 3 or values.shape[0] == 0 or values.shape[1] == 0:
        raise ImageFormatError(f"{path}: texture has shape {values.shape}, expected [H, W, C] with H, W > 0")
    if srgb and not linear_stored:
        colour = min(values.shape[-1], 3) if values.shape[-1] != 2 else 1  # grey+alpha: decode grey only
        values = values.copy()
        values[..., :colour] = np.asarray(srgb_decode(values[..., :colour]))
    return values.astype(np.float32)


def _read_pillow(path: Path) -> tuple[np.ndarray, bool]:
    """(values [H, W, C] float64 in [0, 1] or as stored for float images, whether they are float/linear)."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:  # lazy: the header's size is known before any pixel is decoded
            check_image_size(path, im.height, im.width, len(im.getbands()), "the image header")
            im.load()
            if im.mode == "P":
                im = im.convert("RGBA" if "transparency" in im.info else "RGB")
            elif im.mode in ("CMYK", "YCbCr", "1"):
                im = im.convert("RGB" if im.mode != "1" else "L")
            mode = im.mode
            arr = np.asarray(im)
    except (ImageFormatError, MemoryError):
        raise
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as err:
        raise ImageFormatError(f"{path}: not a readable image ({err})") from err
    # Pillow's plugins parse a corrupt file with plain Python (struct.error, IndexError, TypeError,
    # DecompressionBombError, ...): each means the file is not a readable image.
    except Exception as err:
        raise ImageFormatError(f"{path}: not a readable image ({type(err).__name__}: {err})") from err
    if arr.ndim == 2:
        arr = arr[..., None]
    if mode == "F":
        values = arr.astype(np.float64)
        if not np.all(np.isfinite(values)):
            raise ImageFormatError(f"{path}: float texture has NaN or Inf values")
        return values, True
    if mode not in _SCALE:
        raise ImageFormatError(f"{path}: unsupported image mode {mode!r} (expected 8/16-bit grey, RGB or RGBA)")
    values = arr.astype(np.float64) / _SCALE[mode]
    if np.any(values > 1.0) or np.any(values < 0.0):
        raise ImageFormatError(f"{path}: {mode} samples exceed the 16-bit range")
    return values, False


def head_skin_textures() -> dict[str, np.ndarray]:
    """The head scan's bundled skin textures, decoded, float32 [1024, 1024, C],
    flipped to the project's texture orientation (row 0 at v = 1, as
    ``stage.texel_samples`` lays out its grid and ``relight.image.sample_texture``
    reads):

    * ``"albedo"`` [H, W, 3]: Map-COL.jpg, sRGB-decoded to linear RGB in [0, 1].
    * ``"specular"`` [H, W, 1]: Map-SPEC.jpg's grey level / 255, NOT sRGB-decoded:
      it is a data map (the scan's specular-intensity mask, which three.js,
      the files' source, samples as raw data like any non-colour map); decoding
      would crush the face's median from 0.28 to 0.06. ``read_texture(path)``
      gives the decoded value if wanted.
    * ``"normal"`` [H, W, 3]: the tangent-space normal map, ``2 c / 255 - 1``
      (no sRGB decode: normal maps are linear) renormalised to unit length;
      components along (t = dP/du, b = n x t, n) of ``stage.Surface``
      (OpenGL convention, +Y along b; docs/relight_io.md says how it was checked).

    The scan's files put image row 0 at the mesh's v = 0 as trimesh reports it
    (the GLB's TEXCOORD_0 was made for three.js's default flipY upload, not for
    glTF's v-down rule); the flip here makes texel grid row i equal texture row i
    at 1024^2. Vector components are unchanged by the flip: they are expressed in
    the surface frame, not in image axes.
    """
    out = {}
    for key, name in HEAD_SKIN_FILES.items():
        path = Path(str(resources.files("relight.data").joinpath(name)))
        tex = read_texture(path, srgb=(key == "albedo"))
        if key == "specular":
            tex = tex[..., :1]
        elif key == "normal":
            # From the 8-bit codes themselves, so the float32 rounding of c / 255 is not amplified by the division.
            n = (2.0 * np.round(tex.astype(np.float64)[..., :3] * 255.0) - 255.0) / 255.0
            length = np.linalg.norm(n, axis=-1, keepdims=True)
            # A black texel (0, 0, 0) decodes to (-1, -1, -1), never to 0; the floor only guards the division.
            tex = n / np.maximum(length, 1e-12)
        out[key] = np.ascontiguousarray(tex[::-1], dtype=np.float32)
    return out
