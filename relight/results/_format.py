"""The version field of relight's JSON file formats, checked one way by every reader."""

from __future__ import annotations

from collections.abc import Mapping

__all__ = ["format_version"]


def format_version(doc: Mapping, where: object, newest: int, default: int | None = None,
                   error: type[ValueError] = ValueError) -> int:
    """The ``version`` field of a file's JSON object, checked.

    Args:
        doc: the file's parsed JSON object.
        where: what the error names (the file).
        newest: the newest version this reader knows.
        default: the version of a file without the field (None: the field is required).
        error: the ValueError class raised (``relight.io.ImageFormatError`` for io's readers).

    Returns:
        The version: a positive JSON integer (not a bool or a string) no newer than ``newest``. Raises
        ``error`` naming ``where`` otherwise.
    """
    version = doc.get("version", default)
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise error(f"{where}: field 'version' must be a positive integer, got {version!r}")
    if version > newest:
        raise error(f"{where}: format version {version} is newer than this reader ({newest})")
    return version
