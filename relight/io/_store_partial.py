"""A capture store that survives its writer being killed: the store is built in a folder with a fixed name beside
the target, ``.NAME.partial``, with what it is a store of (``partial.json``) and a journal of checkpoints
(``journal.jsonl``: after each, the chunks complete so far, their digests and the writer's own entry, e.g. which
photographs were converted). A later writer of the same store (the same ``partial.json``) that asks to resume
keeps every chunk a verified checkpoint names and rewrites the rest; one that does not clears the folder.

Used by :class:`relight.io.CaptureStoreWriter` (``partial=...``) and so by ``relight convert --resume``."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from ._json import read_json, write_json
from ._store_chunks import chunk_digest

__all__ = ["PartialStoreMismatch", "append_checkpoint", "partial_folder", "start_partial"]

PARTIAL_FILE = "partial.json"
JOURNAL_FILE = "journal.jsonl"


class PartialStoreMismatch(ValueError):
    """A partial store left by another writer (other inputs or settings) where a resume was asked for."""


def partial_folder(path: Path) -> Path:
    """The folder a resumable writer of the store ``path`` builds it in: ``.NAME.partial`` beside it."""
    return path.parent / f".{path.name}.partial"


def _canonical(doc) -> object:
    """``doc`` as it reads back from JSON (tuples as lists), so that two descriptions compare equal."""
    return json.loads(json.dumps(doc, sort_keys=True, allow_nan=False))


def start_partial(folder: Path, identity: dict, resume: bool) -> list[dict]:
    """Prepare the partial folder of a store described by ``identity``; returns the checkpoints to keep.

    Without ``resume`` (or with no partial folder there) the folder is made afresh (an earlier partial store is
    deleted) and nothing is kept. With ``resume`` and a partial store of the same ``identity``, the journal's
    checkpoints are read in order and kept up to the first whose chunk files are missing or differ from the
    digests it recorded (a torn last line, a truncated chunk): the journal is rewritten to those.

    Args:
        folder: the partial folder (:func:`partial_folder`).
        identity: JSON-able description of the store being written (shape, chunks, rig, inputs, settings).
        resume: keep a matching partial store's checkpoints.

    Returns:
        The kept checkpoints, each ``{"chunks": [[v, l, p], ...], "digests": {key: hex}, "entry": {...}}``.

    Raises:
        PartialStoreMismatch: ``resume`` and the partial store there is of another identity.
        FileExistsError: ``folder`` exists and is not a partial store (it is never deleted).
    """
    identity = _canonical(identity)
    if folder.exists() or folder.is_symlink():
        if not folder.is_dir() or folder.is_symlink() or not (folder / PARTIAL_FILE).is_file():
            raise FileExistsError(f"{folder}: exists and is not a partial capture store; refusing to delete it "
                                  "(move it away)")
        if resume:
            try:
                theirs = read_json(folder / PARTIAL_FILE)
            except (OSError, ValueError):
                theirs = None
            if theirs != identity:
                raise PartialStoreMismatch(f"{folder}: holds the partial store of another conversion (other inputs "
                                           "or settings); run without resuming to start afresh")
            return _verified(folder)
        shutil.rmtree(folder)
    folder.mkdir()
    write_json(folder / PARTIAL_FILE, identity)
    return []


def _verified(folder: Path) -> list[dict]:
    journal = folder / JOURNAL_FILE
    lines = journal.read_text().splitlines() if journal.is_file() else []
    kept = []
    for line in lines:
        try:
            rec = json.loads(line)
            ok = isinstance(rec, dict) and all(_chunk_ok(folder, k, d) for k, d in rec["digests"].items())
        except (ValueError, KeyError, TypeError, AttributeError):
            ok = False
        if not ok:
            break
        kept.append(rec)
    if len(kept) != len(lines):
        tmp = folder / f".{JOURNAL_FILE}.tmp"
        tmp.write_text("".join(json.dumps(r) + "\n" for r in kept))
        os.replace(tmp, journal)
    return kept


def _chunk_ok(folder: Path, key: str, digest: str) -> bool:
    path = folder / key
    if ".." in Path(key).parts or not path.is_file():
        return False
    return chunk_digest(path.read_bytes()) == digest


def append_checkpoint(folder: Path, chunks, digests: dict, entry: dict) -> None:
    """Append one checkpoint to the journal and flush it to disk: the chunks completed since the last one, their
    files' digests and the writer's ``entry``."""
    rec = {"chunks": [list(map(int, k)) for k in chunks], "digests": dict(digests), "entry": _canonical(entry)}
    with open(folder / JOURNAL_FILE, "a") as f:
        f.write(json.dumps(rec) + "\n")
        f.flush()
        os.fsync(f.fileno())
