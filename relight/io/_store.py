"""Capture stores: an OLAT capture as one chunked, compressed Zarr v3 group on
disk, for captures larger than memory (docs/relight_io.md, "Capture store").

Layout (format ``relight-capture-store``, version 2)::

    CAPTURE.zarr/zarr.json            the Zarr v3 group (attributes: relight.format, relight.generation)
    CAPTURE.zarr/radiance/            [V, L, P, C] float32 or float16, chunks (1, Lc, Pc, C)
    CAPTURE.zarr/mask/                [V, L, P] bool, chunks (1, Lc, Pc)
    CAPTURE.zarr/rig.json             as a capture folder's rig.json
    CAPTURE.zarr/cameras.json         as a capture folder's cameras.json
    CAPTURE.zarr/relight-store.json   the manifest, written last: the completion marker

Version 2 adds ``chunk_digests``: the digest of every chunk file of both arrays, so that a store missing a
chunk, or holding a damaged one, is refused by name instead of read as zeros (``_store_chunks.py``).

The manifest records the shape, dtype, channel names, sample_shape [H, W],
``half`` and ``has_valid`` (a capture folder's capture.json fields), the
capture's ``metadata`` (carried over exactly: exposure, noise, the texel
surface of a texel capture), the paths of the two arrays and two JSON files
(each must stay inside the store) and a random ``generation`` id.

Chunking: the consumer is the fitter, which takes every view and light of a
block of samples (``iter_sample_chunks``), so a chunk is one view, ``Lc`` lights
and ``Pc`` contiguous samples, whole channels: a block of Pc samples is
V * ceil(L / Lc) whole-chunk reads and nothing outside it. Pc makes a chunk
about ``TARGET_CHUNK_BYTES`` (2 MiB, uncompressed): big enough that the codec
and the per-chunk overhead of Zarr (a file and an async task each) are small
against the data, small enough that a handful of chunks in flight stays cheap.
``Lc = 8`` (``LIGHT_CHUNK``) is what the writers hold while a chunk fills:
one view's Lc images when the input comes image by image (a capture folder),
and a light block of ``stage.simulate_chunks`` (64 lights) fills 8 chunks at once.

Compression: Blosc (bundled with numcodecs, which zarr requires) with zstd at
level 3 and byte shuffle for the radiance (the float's exponent bytes group
together) and bit shuffle for the mask (8 mask values per byte before zstd);
Blosc splits each chunk into blocks across threads, so it is fast both ways.

Atomicity: a store is built in a hidden temporary sibling
(``.CAPTURE.zarr.<random>.tmp``), the manifest is written last, and the folder
is renamed into place; an existing store at the target is moved aside first
and deleted after (a path that is not a store is never replaced). A reader
refuses a folder without the manifest, and checks the generation id before
and after every read, so a store replaced while open raises
``StoreChangedError`` instead of returning a mix of old and new chunks.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import shutil
import weakref
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

import stage

from ..results import swap_into
from ._capture import _rig_light_count
from ._errors import ImageFormatError, check_radiance, path_inside
from ._json import jsonable, write_json
from ._store_chunks import DIGEST, ChecksummedStore
from ._store_partial import JOURNAL_FILE, PARTIAL_FILE, append_checkpoint, partial_folder, start_partial

__all__ = ["CaptureStoreError", "CaptureStoreWriter", "StoreChangedError", "default_chunks", "is_capture_store",
           "write_capture_store"]

FORMAT = "relight-capture-store"
VERSION = 2
MARKER = "relight-store.json"
# About 2 MiB of uncompressed radiance per chunk (see the module docstring).
TARGET_CHUNK_BYTES = 2 << 20
# Lights per chunk: what a writer holds while chunks fill (Lc images of a view for image-by-image input).
LIGHT_CHUNK = 8
# zstd level 3: zstd's own default, most of the ratio of the higher levels at several times their speed.
_CLEVEL = 3
_DTYPES = {"float32": np.float32, "float16": np.float16}
_ARRAYS = {"radiance": "radiance", "mask": "mask"}
_FILES = {"rig": "rig.json", "cameras": "cameras.json"}


class CaptureStoreError(ImageFormatError):
    """A capture store that cannot be read or written: no completion marker
    (an interrupted write, or not a store), a manifest or array that disagrees
    with itself, or a path in the manifest that leaves the store."""


class StoreChangedError(CaptureStoreError):
    """The store was replaced or removed while a :class:`CaptureStore` had it
    open; reopen it (the read is refused rather than mixing old and new chunks)."""


def default_chunks(shape: Sequence[int], dtype) -> tuple[int, int, int, int]:
    """The chunk shape ``(1, Lc, Pc, C)`` of the module docstring for a
    capture of ``shape`` ``(V, L, P, C)`` and radiance ``dtype``: Lc =
    min(L, LIGHT_CHUNK), Pc the power of two that makes a chunk closest
    below TARGET_CHUNK_BYTES (at most P)."""
    _, n_l, n_p, n_c = (int(s) for s in shape)
    lc = min(n_l, LIGHT_CHUNK)
    per_sample = lc * n_c * np.dtype(dtype).itemsize
    pc = 1 << max(0, int(math.floor(math.log2(max(1, TARGET_CHUNK_BYTES // per_sample)))))
    return 1, lc, min(n_p, pc), n_c


def is_capture_store(path: str | os.PathLike) -> bool:
    """Whether ``path`` is meant as a capture store: a folder holding the
    manifest or a Zarr group (``zarr.json``), or a ``.zarr`` folder. (An
    incomplete one is refused by :func:`open_capture_store`, naming why.)"""
    p = Path(path)
    return p.is_dir() and ((p / MARKER).is_file() or (p / "zarr.json").is_file() or p.suffix == ".zarr")


def _inside(root: Path, rel, where: str, field: str) -> Path:
    """``root / rel`` if that stays inside ``root`` (symlinks resolved), else CaptureStoreError."""
    return path_inside(root, rel, f"{where}: field '{field}'", what=f"the store {root}",
                       error=CaptureStoreError).resolve()


def _check_target(path: Path) -> Path:
    """The parent must exist; an existing ``path`` must be a store (it is replaced)."""
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise FileNotFoundError(f"{path}: cannot write, folder {parent} does not exist")
    if (path.exists() or path.is_symlink()) and not (path.is_dir() and (path / MARKER).is_file()):
        raise FileExistsError(f"{path}: exists and is not a capture store; refusing to replace it")
    return parent


def _swap_in(tmp: Path, path: Path) -> None:
    """Rename the finished ``tmp`` to ``path`` (which must be a store or absent): :func:`swap_folder`."""
    _check_target(path)
    swap_folder(tmp, path)


def swap_folder(tmp: Path, path: Path) -> None:
    """Rename the finished folder ``tmp`` to ``path``, replacing what is there:
    :func:`relight.results.swap_into`, the one folder swap (an atomic
    exchange where the OS has one; else the old folder moved aside first and
    deleted after, so readers see the old set, then for a moment nothing,
    then the new one, never a mix). The caller decides what may be replaced."""
    swap_into(Path(tmp), Path(path))


def _codecs(kind: str):
    from zarr.codecs import BloscCodec

    return BloscCodec(cname="zstd", clevel=_CLEVEL, shuffle="bitshuffle" if kind == "mask" else "shuffle")


def _rig_doc(rig) -> dict:
    return stage.rig_to_dict(rig) if isinstance(rig, stage.Rig) else dict(rig)


def _camera_docs(cameras, n_views: int) -> list:
    if cameras is None:
        return [{"name": f"view{v}"} for v in range(n_views)]
    return [stage.camera_to_dict(c, f"cam{i:03d}") if isinstance(c, stage.Camera) else c
            for i, c in enumerate(cameras)]


def _span(sel, n: int, what: str) -> tuple[int, int]:
    """(start, stop) of a step-1 slice or an int along an axis of length ``n``."""
    if isinstance(sel, (int, np.integer)):
        i = int(sel)
        if not 0 <= i < n:
            raise ValueError(f"{what} {i} out of range [0, {n})")
        return i, i + 1
    if not isinstance(sel, slice) or sel.step not in (None, 1):
        raise ValueError(f"{what} must be an int or a slice with step 1, got {sel!r}")
    start, stop, _ = sel.indices(n)
    if stop <= start:
        raise ValueError(f"{what} {sel!r} selects nothing of {n}")
    return start, stop


class CaptureStoreWriter:
    """Write a capture store chunk by chunk (a context manager).

    ``write(view, light_slice, sample_slice, radiance [Lc, Pc, C], mask [Lc, Pc])``
    takes the blocks ``stage.simulate_chunks`` yields (or one image at a time,
    ``radiance [1, P, C]``), in any order and of any size; every element must
    be written exactly once. Blocks are gathered into whole chunks in memory
    and each chunk is written once it is complete, so nothing is read back and
    memory holds only the chunks being filled. ``close()`` checks that every
    chunk was written, writes rig.json, cameras.json and the manifest last,
    and renames the store into place (replacing an existing store); leaving
    the ``with`` block by an exception (or ``abort()``) deletes the temporary
    store and leaves the target as it was.

    Args:
        path: the store folder to create (conventionally ``*.zarr``).
        shape: ``(V, L, P, C)``.
        dtype: float32 or float16 radiance.
        rig: a ``stage.Rig`` (stored as ``stage.rig_to_dict``) or a rig dict
            (a capture folder's rig.json) with L lights.
        cameras: V ``stage.Camera`` s or camera dicts (default ``{"name": "view<i>"}``).
        metadata: JSON-able dict (capture.json's metadata: exposure, noise, surface...).
        chunks: ``(Vc, Lc, Pc, C)``; default :func:`default_chunks`.
        sample_shape: ``(H, W)``, ``H * W = P`` (default ``(1, P)``).
        channels: channel names (default R, G, B for C = 3, Y for C = 1).
        has_valid: whether the mask is meaningful (a capture folder without
            a ``valid`` channel stores an all-True mask and says so).
        progress: ``stage.Progress``, phase "write store", counting chunks.
        partial: make the writer resumable: a JSON-able description of what the store is of (its inputs and
            settings; the shape, chunks, rig, cameras and metadata are added). The store is then built in
            ``.NAME.partial`` beside ``path`` (``relight.io._store_partial``) under an output lock on ``path``,
            :meth:`checkpoint` records progress, and leaving the ``with`` block by an exception keeps the partial
            store for a later writer (:meth:`abort` deletes it).
        resume: with ``partial``: keep the chunks that the verified checkpoints of an earlier writer of the same
            store name (``checkpoints`` lists their entries); without it an earlier partial store is cleared.

    Raises ValueError naming the argument on bad shapes or types, FileNotFoundError
    when the parent folder is missing, FileExistsError when ``path`` exists and
    is not a store; with ``resume``, ``PartialStoreMismatch`` (a ValueError) when the partial store there is of
    other inputs or settings, and ``relight.results.FolderLockedError`` when another writer holds ``path``.
    """

    def __init__(self, path: str | os.PathLike, shape: Sequence[int], dtype=np.float32, rig=None, cameras=None,
                 metadata: Mapping | None = None, chunks: Sequence[int] | None = None, *,
                 sample_shape: Sequence[int] | None = None, channels: Sequence[str] | None = None,
                 has_valid: bool = True, progress: stage.Progress | None = None, partial: Mapping | None = None,
                 resume: bool = False):
        import zarr

        self.path = Path(path)
        shape = tuple(int(s) for s in shape)
        if len(shape) != 4 or min(shape) < 1:
            raise ValueError(f"{self.path}: shape must be (V, L, P, C) of positive sizes, got {shape}")
        self.shape = shape
        V, L, P, C = shape
        name = np.dtype(dtype).name
        if name not in _DTYPES:
            raise ValueError(f"{self.path}: dtype must be float32 or float16, got {name}")
        self.dtype = np.dtype(name)
        if rig is None:
            raise ValueError(f"{self.path}: rig is required (a stage.Rig or a rig dict)")
        self._rig = _rig_doc(rig)
        if _rig_light_count(self._rig, f"{self.path}: rig") != L:
            raise ValueError(f"{self.path}: rig has {_rig_light_count(self._rig, self.path)} lights but shape has {L}")
        self._cameras = _camera_docs(cameras, V)
        if len(self._cameras) != V:
            raise ValueError(f"{self.path}: {len(self._cameras)} cameras given for {V} views")
        self._metadata = jsonable(dict(metadata or {}))
        try:
            json.dumps(self._metadata, allow_nan=False)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{self.path}: metadata is not JSON-able ({err})") from None
        hw = tuple(int(s) for s in sample_shape) if sample_shape is not None else (1, P)
        if len(hw) != 2 or hw[0] * hw[1] != P:
            raise ValueError(f"{self.path}: sample_shape {hw} does not hold {P} samples")
        self.sample_shape = hw
        names = list(channels) if channels is not None else {1: ["Y"], 3: ["R", "G", "B"]}.get(C)
        if names is None or len(names) != C or "valid" in names:
            raise ValueError(f"{self.path}: channels must be {C} names (not 'valid'), got {names}")
        self.channels = names
        self.has_valid = bool(has_valid)
        ch = tuple(int(c) for c in chunks) if chunks is not None else default_chunks(shape, self.dtype)
        if len(ch) != 4 or min(ch) < 1 or ch[3] != C:
            raise ValueError(f"{self.path}: chunks must be (Vc, Lc, Pc, C={C}) of positive sizes, got {ch}")
        self.chunks = tuple(min(c, s) for c, s in zip(ch, shape, strict=True))
        self._grid = tuple(-(-s // c) for s, c in zip(shape[:3], self.chunks[:3], strict=True))
        self._total = int(np.prod(self._grid))
        self._done: set[tuple[int, int, int]] = set()
        self._pending: dict[tuple[int, int, int], list] = {}
        self._generation = secrets.token_hex(16)
        self._closed = False
        self.checkpoints: list[dict] = []
        self._journaled: set[tuple[int, int, int]] = set()
        parent = _check_target(self.path)
        self._partial, self._lock, records = partial is not None, None, []
        if self._partial:
            from ..results import FolderLock

            self._lock = FolderLock(self.path, "a capture store writer").acquire()
            self._tmp = partial_folder(self.path)
            try:
                records = start_partial(self._tmp, self._identity(partial), bool(resume))
            except BaseException:
                self._lock.release()
                raise
            self._cleanup = weakref.finalize(self, self._lock.release)
        else:
            self._tmp = parent / f".{self.path.name}.{secrets.token_hex(6)}.tmp"
            self._tmp.mkdir()  # permissions as a plain mkdir gives them (mkdtemp's are private)
            # A writer dropped without close() or abort() leaves no temporary folder behind either.
            self._cleanup = weakref.finalize(self, shutil.rmtree, str(self._tmp), True)
        # write_empty_chunks: every chunk is on disk, so a store missing a chunk file is damaged, not zeros.
        cfg = {"write_empty_chunks": True}
        try:
            self._store = ChecksummedStore(self._tmp, arrays=tuple(_ARRAYS.values()))
            if records:
                self._reopen(zarr.open_group(store=self._store, mode="r+", zarr_format=3), cfg, records)
                self._bar = stage.Phase(progress, "write store", self._total)
                self._bar.advance(len(self._done))
                return
            # (mode "a" for a partial store: "w" would delete its partial.json; the folder is fresh either way.)
            root = zarr.open_group(store=self._store, mode="a" if self._partial else "w", zarr_format=3,
                                   attributes={"relight": {"format": FORMAT, "version": VERSION,
                                                           "generation": self._generation}})
            self._radiance = root.create_array(
                _ARRAYS["radiance"], shape=shape, chunks=self.chunks, dtype=self.dtype.name,
                compressors=_codecs("radiance"), fill_value=0, config=cfg,
                dimension_names=("view", "light", "sample", "channel"))
            self._mask = root.create_array(
                _ARRAYS["mask"], shape=shape[:3], chunks=self.chunks[:3], dtype="bool",
                compressors=_codecs("mask"), fill_value=False, config=cfg,
                dimension_names=("view", "light", "sample"))
        except BaseException:
            self.abort()
            raise
        self._bar = stage.Phase(progress, "write store", self._total)

    def _identity(self, partial: Mapping) -> dict:
        V, L, P, C = self.shape
        return {"of": jsonable(dict(partial)), "shape": [V, L, P, C], "dtype": self.dtype.name,
                "chunks": list(self.chunks), "sample_shape": list(self.sample_shape), "channels": self.channels,
                "has_valid": self.has_valid, "rig": self._rig, "cameras": self._cameras, "metadata": self._metadata}

    def _reopen(self, root, cfg, records: list[dict]) -> None:
        """Open the arrays of a partial store and take over its verified checkpoints."""
        self._generation = str(root.attrs["relight"]["generation"])
        self._radiance = root[_ARRAYS["radiance"]].with_config(cfg)
        self._mask = root[_ARRAYS["mask"]].with_config(cfg)
        for rec in records:
            keys = {tuple(int(i) for i in k) for k in rec["chunks"]}
            self._done |= keys
            self._journaled |= keys
            self._store.digests.update(rec["digests"])
            self.checkpoints.append(rec["entry"])

    def __enter__(self) -> CaptureStoreWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        elif self._partial:  # kept for a writer that resumes
            self._closed = True
            self._pending.clear()
            self._cleanup()
        else:
            self.abort()

    def written(self, view: int, light_slice: slice) -> bool:
        """Whether every chunk of ``view`` under the lights ``light_slice`` (all samples) is written."""
        cv, cl, cp, _ = self.chunks
        l0, l1 = _span(light_slice, self.shape[1], "light_slice")
        return all((view // cv, lk, pk) in self._done for lk in range(l0 // cl, (l1 - 1) // cl + 1)
                   for pk in range(self._grid[2]))

    def checkpoint(self, entry: Mapping) -> None:
        """Record progress (resumable writers only): the chunks complete since the last checkpoint, their digests
        and ``entry`` (JSON-able: what the caller needs to skip that work when it resumes), flushed to disk."""
        if not self._partial:
            raise ValueError(f"{self.path}: checkpoint needs a resumable writer (partial=...)")
        new = self._done - self._journaled
        files = {f: self._store.digests[f] for v, l, p in new
                 for f in (f"{_ARRAYS['radiance']}/c/{v}/{l}/{p}/0", f"{_ARRAYS['mask']}/c/{v}/{l}/{p}")}
        append_checkpoint(self._tmp, sorted(new), files, jsonable(dict(entry)))
        self._journaled |= new

    def _chunk_box(self, key):
        return tuple(slice(k * c, min((k + 1) * c, s)) for k, c, s in zip(key, self.chunks, self.shape, strict=False))

    def write(self, view, light_slice, sample_slice, radiance, mask=None) -> None:
        """Store ``radiance`` [nL, nP, C] (or [1, nL, nP, C]) and ``mask`` [nL, nP]
        (bool; None: all valid) at ``view`` (an int), ``light_slice`` and
        ``sample_slice`` (ints or step-1 slices). ValueError naming the argument on
        a wrong shape, NaN / negative radiance, or an element written twice."""
        if self._closed:
            raise ValueError(f"{self.path}: writer is closed")
        V, L, P, C = self.shape
        v0, _ = _span(view, V, "view")
        l0, l1 = _span(light_slice, L, "light_slice")
        p0, p1 = _span(sample_slice, P, "sample_slice")
        rad = np.asarray(radiance)
        if rad.ndim == 4 and rad.shape[0] == 1:
            rad = rad[0]
        if rad.shape != (l1 - l0, p1 - p0, C):
            raise ValueError(f"{self.path}: radiance must be {(l1 - l0, p1 - p0, C)} for lights {l0}:{l1}, "
                             f"samples {p0}:{p1}, got {rad.shape}")
        check_radiance(rad, self.path, f"radiance of view {v0} lights {l0}:{l1}")
        rad = rad.astype(self.dtype, copy=False)
        if mask is None:
            msk = np.ones(rad.shape[:2], bool)
        else:
            msk = np.asarray(mask)
            if msk.ndim == 3 and msk.shape[0] == 1:
                msk = msk[0]
            if msk.shape != rad.shape[:2]:
                raise ValueError(f"{self.path}: mask must be {rad.shape[:2]}, got {msk.shape}")
            msk = msk.astype(bool, copy=False)
        cv, cl, cp, _ = self.chunks
        vk = v0 // cv
        for lk in range(l0 // cl, (l1 - 1) // cl + 1):
            for pk in range(p0 // cp, (p1 - 1) // cp + 1):
                key = (vk, lk, pk)
                box = self._chunk_box(key)
                if key in self._done:
                    raise ValueError(f"{self.path}: view {v0} lights {l0}:{l1} samples {p0}:{p1} overlap a chunk "
                                     "already written")
                buf = self._pending.get(key)
                if buf is None:
                    ext = tuple(b.stop - b.start for b in box)
                    buf = [np.zeros((*ext, C), self.dtype), np.zeros(ext, bool), np.zeros(ext, bool)]
                    self._pending[key] = buf
                # The intersection of the block with this chunk, in chunk and in block coordinates.
                a0, a1 = max(l0, box[1].start), min(l1, box[1].stop)
                b0, b1 = max(p0, box[2].start), min(p1, box[2].stop)
                at = (v0 - box[0].start, slice(a0 - box[1].start, a1 - box[1].start),
                      slice(b0 - box[2].start, b1 - box[2].start))
                src = (slice(a0 - l0, a1 - l0), slice(b0 - p0, b1 - p0))
                if buf[2][at].any():
                    raise ValueError(f"{self.path}: view {v0} lights {a0}:{a1} samples {b0}:{b1} written twice")
                buf[0][at] = rad[src]
                buf[1][at] = msk[src]
                buf[2][at] = True
                if buf[2].all():
                    self._radiance[box] = buf[0]
                    self._mask[box] = buf[1]
                    del self._pending[key]
                    self._done.add(key)
                    self._bar.advance(1)

    def add_metadata(self, entries: Mapping) -> None:
        """Add JSON-able ``entries`` to the metadata the manifest records at :meth:`close` (what is known only
        once the data is written: a conversion's report). ValueError when they are not JSON-able."""
        extra = jsonable(dict(entries))
        try:
            json.dumps(extra, allow_nan=False)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{self.path}: metadata is not JSON-able ({err})") from None
        self._metadata.update(extra)

    def abort(self) -> None:
        """Delete the temporary (or partial) store; the target is left as it was."""
        self._closed = True
        self._pending.clear()
        self._cleanup()
        if self._partial:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def close(self) -> Path:
        """Commit: every chunk written, then rig.json, cameras.json, the manifest
        (last) and the rename into place. Returns the store's path. An
        incomplete capture is not committed: ValueError naming what is missing
        (the temporary store is deleted)."""
        if self._closed:
            return self.path
        try:
            missing = self._total - len(self._done)
            if missing:
                raise ValueError(f"{self.path}: capture incomplete, {missing} of {self._total} chunks not fully "
                                 f"written ({len(self._pending)} partly); nothing was committed")
            digests = {name: {k.split("/", 1)[1]: d for k, d in self._store.digests.items()
                              if k.startswith(f"{name}/")} for name in _ARRAYS.values()}
            if sum(map(len, digests.values())) != 2 * self._total:
                raise ValueError(f"{self.path}: {sum(map(len, digests.values()))} chunk files written for "
                                 f"{2 * self._total} chunks; nothing was committed")
            write_json(self._tmp / _FILES["rig"], self._rig, indent=1)
            write_json(self._tmp / _FILES["cameras"], self._cameras, indent=1)
            V, L, P, C = self.shape
            manifest = {"format": FORMAT, "version": VERSION, "generation": self._generation,
                        "shape": [V, L, P, C], "dtype": self.dtype.name, "chunks": list(self.chunks),
                        "sample_shape": list(self.sample_shape), "channels": self.channels,
                        "half": self.dtype == np.float16, "has_valid": self.has_valid,
                        "arrays": dict(_ARRAYS), "files": dict(_FILES),
                        "codec": {"name": "blosc", "cname": "zstd", "clevel": _CLEVEL},
                        "chunk_digests": {"digest": DIGEST, **digests},
                        "metadata": self._metadata}
            write_json(self._tmp / MARKER, manifest, indent=1)
            for name in (PARTIAL_FILE, JOURNAL_FILE):
                (self._tmp / name).unlink(missing_ok=True)
            _swap_in(self._tmp, self.path)
        except BaseException:
            self.abort()
            raise
        self._closed = True
        if self._partial:
            self._cleanup()  # the lock
        else:
            self._cleanup.detach()
        return self.path


def write_capture_store(path: str | os.PathLike, capture: stage.Capture, *, metadata: Mapping | None = None,
                        chunks: Sequence[int] | None = None, progress: stage.Progress | None = None,
                        sample_shape: Sequence[int] | None = None, channels: Sequence[str] | None = None) -> Path:
    """Write a ``stage.Capture`` (in memory) as a capture store, atomically, in
    its radiance dtype (float32 or float16); one view and light chunk at a
    time, so the only copy beyond the capture is one chunk row. See
    :class:`CaptureStoreWriter` for the arguments. The capture's sensor is not
    stored (record it in ``metadata``). Returns the store's path."""
    V, L, P, C = capture.shape
    dtype = np.dtype(capture.radiance.dtype)
    with CaptureStoreWriter(path, (V, L, P, C), dtype, capture.rig, capture.cameras, metadata, chunks,
                            sample_shape=sample_shape, channels=channels, progress=progress) as w:
        cl = w.chunks[1]
        for v in range(V):
            for l0 in range(0, L, cl):
                ls = slice(l0, min(l0 + cl, L))
                w.write(v, ls, slice(None), np.asarray(capture.radiance[v, ls]), np.asarray(capture.mask[v, ls]))
    return Path(path)
