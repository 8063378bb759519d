"""Accepting a deliberate edit of a result set: its manifest rewritten over the files as they now are.

A reader refuses a set whose files differ from its manifest (``ResultSet.check``): the manifest cannot tell an
edit from old and new files mixed by an interrupted writer. A user who edited a set on purpose (new rig
intensities after a recalibration, a retouched map) says so with :func:`reseal` (``relight reseal FOLDER``),
which hashes the folder again and records the previous generation."""

from __future__ import annotations

import datetime
import os
from pathlib import Path

from ._lock import FolderLock
from ._resultset import _set_files, open_result_set, write_manifest

# The manifest's own fields, which write_manifest sets; every other field is the writer's and is kept.
_OWN = ("format", "version", "kind", "generation", "created", "writer", "files", "unhashed")


def reseal(folder: str | os.PathLike) -> dict:
    """Accept hand edits of a result set: rewrite its manifest over the files as they now are.

    Holds the folder's lock (:class:`relight.results.FolderLock`) so no command writes it meanwhile. The set
    keeps its kind, its unhashed prefixes and its writer's extra fields; it gets a new generation, and
    ``resealed`` records the previous generation and the time. A file's content is not checked for sense:
    a reader still validates what it reads (an edited rig.json must still be a rig).

    Args:
        folder: the result set's folder (a command's output, with ``relight-set.json``).

    Returns:
        ``{"changed": [...], "added": [...], "removed": [...]}``: the set's relative paths whose size or
        SHA-256 differ from the old manifest, that it did not list, and that it listed but are gone.
        Raises :class:`relight.results.ResultSetError` naming the folder when it holds no valid manifest.
    """
    folder = Path(folder)
    with FolderLock(folder, "relight reseal"):
        rs = open_result_set(folder)
        doc = rs.manifest
        unhashed = list(doc.get("unhashed") or [])
        before = rs.files
        now = set(_set_files(folder, unhashed))
        extra = {k: v for k, v in doc.items() if k not in _OWN}
        extra["resealed"] = {"previous_generation": rs.generation,
                             "at": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}
        new = write_manifest(folder, rs.kind, unhashed, **extra)
    files = new["files"]
    return {"changed": sorted(r for r in now & set(before) if files[r] != before[r]),
            "added": sorted(now - set(before)),
            "removed": sorted(set(before) - now)}
