"""Errors raised at the file boundary, and the radiance checks shared by readers.

Every message names the file, the field and what was expected (DESIGN.md,
"Bad input is refused at the boundary").
"""

from __future__ import annotations

import contextlib
import os
import re
import string
from collections.abc import Iterator, Mapping
from pathlib import Path, PurePosixPath

import numpy as np

from ..results import ResultSetError
from ..results import format_version as _format_version

__all__ = ["MAX_IMAGE_PIXELS", "MAX_PATH_CHARS", "MAX_RADIANCE", "ImageFormatError", "check_finite_output",
           "check_image_size", "check_radiance", "existing_file", "file_name", "path_inside", "path_template",
           "set_refusal_as"]

# The largest image a reader decodes: 2^28 pixels (16384 x 16384, 3 GiB as float32 RGB). Readers check a
# file's declared size against it before allocating anything, so a corrupt or hostile header (an HDR saying
# 200000 x 200000) is refused with a named error instead of a MemoryError. stage.MAX_CAMERA_PIXELS is the
# same number for cameras.json. Readers look it up at call time, so a test may lower it.
MAX_IMAGE_PIXELS = 2**28

# The largest radiance accepted as input (check_radiance). Float32 sums and products downstream (light
# weights times captures summed over ~10^3 lights, squared residuals summed over ~10^7 samples) stay finite
# for values up to 1e15, which is still six orders of magnitude above the sun's luminance in cd m^-2.
# RGBE alone can hold 1.7e38, where the sum of one pixel's three channels is Inf.
MAX_RADIANCE = 1e15

# The longest relative path a user's file may name (path_inside); Linux's PATH_MAX is 4096, and an
# over-long name would surface as an OSError from the first os call instead of an error naming the field.
MAX_PATH_CHARS = 1024
# The longest name a user's file may give to something that becomes one file or folder name (file_name): most
# file systems' NAME_MAX, in UTF-8 bytes.
MAX_NAME_BYTES = 255


class ImageFormatError(ValueError):
    """A file that is not a valid image of the expected format (corrupt,
    truncated, wrong magic, missing channel, inconsistent sizes)."""


@contextlib.contextmanager
def set_refusal_as(where: str | os.PathLike, error: type[ImageFormatError] = ImageFormatError) -> Iterator[None]:
    """Give a reader's result-set refusal as the reader's own file-format error.

    A folder written as a result set is read only if its files are the ones its manifest lists
    (``relight.results.ResultSet.check``). A :class:`relight.results.ResultSetError` raised inside the block
    (no manifest, a file missing, not listed or differing from the manifest: a mix of two writes) is raised
    again as ``error`` (chained, ``from`` the original), so that every refusal of a reader is caught as one
    file-format error.

    Args:
        where: the folder read; the message names it (the original message, if it does already).
        error: the reader's error class (:class:`ImageFormatError` or a subclass).

    Returns:
        A context manager.
    """
    try:
        yield
    except ResultSetError as exc:
        msg = str(exc)
        raise error(msg if str(where) in msg else f"{where}: {msg}") from exc


def path_inside(folder: str | os.PathLike, rel: object, where: str, *, what: str = "the folder",
                error: type[ValueError] = ImageFormatError) -> Path:
    """``folder / rel`` for a path read from a user's file, refusing what would
    leave ``folder``: a non-string or empty value (or one with a NUL byte or
    longer than ``MAX_PATH_CHARS``), an absolute path (POSIX or
    Windows drive), ``..`` components, and links that resolve outside. The
    error (``error``, default :class:`ImageFormatError`) names ``where``."""
    if not isinstance(rel, str) or not rel or "\0" in rel or len(rel) > MAX_PATH_CHARS:
        shown = repr(rel) if len(repr(rel)) <= 80 else repr(rel)[:77] + "..."
        raise error(f"{where}: must be a relative path inside {what} (at most {MAX_PATH_CHARS} characters, "
                    f"no NUL byte), got {shown}")
    pure = PurePosixPath(rel.replace("\\", "/"))
    if pure.is_absolute() or Path(rel).is_absolute() or ".." in pure.parts or (pure.parts and ":" in pure.parts[0]):
        raise error(f"{where}: path {rel!r} leaves {what} (absolute paths and '..' are refused)")
    folder = Path(folder)
    path = folder / Path(*pure.parts)
    if not path.resolve().is_relative_to(folder.resolve()):
        raise error(f"{where}: path {rel!r} leads outside {what} (through a link)")
    return path


def file_name(name: object, where: str, *, error: type[ValueError] = ImageFormatError) -> str:
    """``name``, read from a user's file, checked as one plain file-name component before anything makes it a
    path (a camera's name becomes its image folder, say): a non-empty string of at most ``MAX_NAME_BYTES``
    UTF-8 bytes with no path separator (``/``, ``\\``), drive colon, control character or NUL, and not ``.``
    or ``..``. Anything else could name a file outside the output folder, or a different one on another
    system. Raises ``error`` (default :class:`ImageFormatError`) naming ``where``."""
    shown = repr(name) if len(repr(name)) <= 80 else repr(name)[:77] + "..."
    if not isinstance(name, str) or not name:
        raise error(f"{where}: must be a non-empty file name (a string), got {shown}")
    bad = sorted({c for c in name if c in '/\\:' or ord(c) < 32 or ord(c) == 127})
    if bad or name in (".", "..") or len(name.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
        why = (f"it holds {', '.join(repr(c) for c in bad)}" if bad else
               "'.' and '..' name folders" if name in (".", "..") else f"it is over {MAX_NAME_BYTES} bytes")
        raise error(f"{where}: {shown} is not a plain file name ({why}); it would become a path, so it must be "
                    "one name with no '/', '\\', ':' or control characters")
    return name


def path_template(template: object, fields: Mapping[str, object], required: tuple[str, ...], where: str) -> str:
    """``template`` checked as a file-name pattern read from a user's file: a
    ``str.format`` string whose fields are only names from ``fields`` (no
    attribute or index access), with every name in ``required``, literal
    format specs (no field nested in a spec: ``{light:{light}{light}}`` makes
    the light index a width, 345345345 characters at light 345) of widths
    under 1000, formatting ``fields``' trial values (name -> value) without
    error into at most ``MAX_PATH_CHARS`` characters and no NUL byte. Raises
    :class:`ImageFormatError` naming ``where``."""
    if not isinstance(template, str) or not template:
        raise ImageFormatError(f"{where}: must be a path template string, got {template!r}")
    shown = repr(template) if len(template) <= 80 else repr(template[:77]) + "..."
    try:
        parsed = [(f, spec or "") for _, f, spec, _ in string.Formatter().parse(template) if f is not None]
        nested = [f for _, spec in parsed for _, f, _, _ in string.Formatter().parse(spec) if f is not None]
    except ValueError as err:
        raise ImageFormatError(f"{where}: {shown} is not a format string ({err})") from None
    if nested:
        # A field inside a spec turns an index into a width or a precision, which no trial value bounds.
        raise ImageFormatError(f"{where}: {shown} nests fields {nested} in a format spec; specs must be literal "
                               "(e.g. {light:03d})")
    names = [f for f, _ in parsed] + nested
    if any(f not in fields for f in names) or any(r not in names for r in required):
        allowed = ", ".join("{" + f + "}" for f in fields)
        raise ImageFormatError(f"{where}: {shown} may use only {allowed} (and needs "
                               f"{', '.join('{' + r + '}' for r in required)}), got fields {names}")
    # Format specs are free ("{light:03d}"), but a width of 1000 or more would build a path of that many
    # characters (at a million, the memory for it) before anything else could refuse it.
    if any(re.search(r"\d{4,}", spec) for _, spec in parsed):
        raise ImageFormatError(f"{where}: {shown} has a field width of 1000 or more characters")
    try:  # one trial, so a spec the values refuse ("{light:s}") is named here
        sample = template.format(**fields)
    except (ValueError, TypeError, AttributeError, KeyError, IndexError) as err:
        raise ImageFormatError(f"{where}: {shown} does not format {dict(fields)} "
                               f"({type(err).__name__}: {err})") from None
    if len(sample) > MAX_PATH_CHARS or "\0" in sample:
        raise ImageFormatError(f"{where}: {shown} gives a path of {len(sample)} characters (at most "
                               f"{MAX_PATH_CHARS}) or one with a NUL byte")
    return template


def format_version(doc: Mapping, where: object, newest: int, default: int | None = None,
                   error: type[ValueError] = ImageFormatError) -> int:
    """``relight.results.format_version`` raising :class:`ImageFormatError` by default.

    Args:
        doc, where, newest, default, error: as ``relight.results.format_version``'s.

    Returns:
        The file's format version.
    """
    return _format_version(doc, where, newest, default, error)


def check_image_size(path: str | os.PathLike, height: int, width: int, channels: int = 1,
                     what: str = "image") -> None:
    """Refuse a declared image size before allocating it: both sides >= 1 and
    ``height * width`` at most :data:`MAX_IMAGE_PIXELS` (``channels`` is only
    reported). Raises :class:`ImageFormatError` naming the file."""
    h, w = int(height), int(width)
    if h <= 0 or w <= 0:
        raise ImageFormatError(f"{path}: {what} declares an empty size {w}x{h} (width x height)")
    if h * w > MAX_IMAGE_PIXELS:
        raise ImageFormatError(f"{path}: {what} declares {w}x{h} pixels ({channels} channel(s)), more than the "
                               f"reader's limit of {MAX_IMAGE_PIXELS} pixels (relight.io._errors.MAX_IMAGE_PIXELS)")


def existing_file(path: str | os.PathLike, what: str, missing: type[Exception] = FileNotFoundError) -> Path:
    """``path`` as a Path when it is a regular file (links followed): ``stage.existing_path``, the one rule for a
    user's file, with ImageFormatError for something that is not a regular file (a folder, a FIFO, a
    device, a socket) and ``missing`` (FileNotFoundError by default) saying "no such {what}" when nothing is
    there. Every image reader uses it (issue 29: a FIFO given as an env map was "no such HDR file")."""
    import stage

    return stage.existing_path(path, what, error=ImageFormatError, missing=missing)


def check_finite_output(values: np.ndarray, path: str | os.PathLike, what: str = "image") -> None:
    """Refuse to write an output image holding NaN or Inf: ImageFormatError naming the file, the count and the
    first offending index. Every radiance image a command writes (relit images, previews, photographs, the demo's
    relit pair) passes through it, so a non-finite pixel ends the command with one line instead of an EXR that
    poisons whatever reads it (the reported case: a photo capture's ``"exposure": 1e-300`` rendered relit.exr with
    2091 NaN pixels, exit 0)."""
    values = np.asarray(values)
    if not np.issubdtype(values.dtype, np.floating):
        return
    bad = _non_finite(values)
    if bad:
        raise ImageFormatError(f"{path}: {what} has {bad}; not written. An input beyond range (an exposure, gain "
                               "or intensity near 0 or huge) or a bug: check the inputs, and report it if they are "
                               "sound")


def _non_finite(values: np.ndarray) -> str:
    """"N NaN/Inf values (first at index (i, j, ...))" for an array holding any, else "": the one account of
    non-finite values that the input (:func:`check_radiance`) and output (:func:`check_finite_output`) checks give."""
    bad = ~np.isfinite(values)
    if not bad.any():
        return ""
    idx = tuple(int(i) for i in np.argwhere(bad)[0])
    return f"{int(bad.sum())} NaN/Inf values (first at index {idx})"


def check_radiance(values: np.ndarray, path: str | os.PathLike, what: str = "radiance") -> None:
    """Refuse NaN, Inf, negative values or values above :data:`MAX_RADIANCE` in
    an input radiance array.

    Radiance is a non-negative physical quantity (W sr^-1 m^-2, or relative
    units); a NaN or a negative value in a capture or an environment map is a
    broken file or a broken upstream tool, and would silently poison every sum
    (light weights, relighting) downstream. The message gives the count and the
    first offending index so the pixel can be inspected.
    """
    values = np.asarray(values)
    bad = _non_finite(values)
    if bad:
        raise ImageFormatError(f"{path}: {what} has {bad}; expected finite, non-negative radiance")
    neg = values < 0
    if neg.any():
        idx = tuple(int(i) for i in np.argwhere(neg)[0])
        raise ImageFormatError(
            f"{path}: {what} has {int(neg.sum())} negative values (first at index {idx}, "
            f"value {float(values[idx]):.6g}); expected non-negative radiance"
        )
    # float16 (max 65504) cannot exceed the limit, and comparing it with 1e15 would overflow the cast.
    small = values.dtype.kind == "f" and float(np.finfo(values.dtype).max) <= MAX_RADIANCE
    big = np.zeros(values.shape, bool) if small else values > MAX_RADIANCE
    if big.any():
        idx = tuple(int(i) for i in np.argwhere(big)[0])
        raise ImageFormatError(
            f"{path}: {what} has {int(big.sum())} values above {MAX_RADIANCE:.0e} (first at index {idx}, "
            f"value {float(values[idx]):.6g}); float32 sums of such values overflow (relight.io._errors.MAX_RADIANCE)"
        )
