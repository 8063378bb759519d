"""Reading capture stores (the format is described in ``_store.py``): :class:`CaptureStore`, opened by
:func:`open_capture_store`, reads radiance and mask chunk by chunk and checks the store's generation around every
read; :func:`capture_folder_to_store` and :func:`store_to_capture_folder` convert between the two containers one
image at a time.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import stage

from ..results import MANIFEST as RESULT_MANIFEST
from ..results import open_result_set
from ._capture import _FILES as _FOLDER_FILES
from ._capture import _FORMAT as _FOLDER_FORMAT
from ._capture import _VERSION as _FOLDER_VERSION
from ._capture import _atomic_folder, _rig_light_count, open_capture
from ._errors import ImageFormatError, set_refusal_as
from ._exr import write_exr_channels
from ._json import read_json, write_json
from ._store import (
    _ARRAYS,
    _DTYPES,
    _FILES,
    FORMAT,
    MARKER,
    VERSION,
    CaptureStoreError,
    CaptureStoreWriter,
    StoreChangedError,
    _inside,
)
from ._store_chunks import DIGEST, ChecksummedStore, DamagedChunkError, chunk_keys

__all__ = ["CaptureStore", "capture_folder_to_store", "open_capture_store", "store_to_capture_folder"]


def _selector(sel, n: int, what: str, where):
    """A zarr orthogonal selector for one axis: a slice, or a sorted-as-given int array."""
    if sel is None:
        return slice(None)
    if isinstance(sel, slice):
        if sel.step is not None and sel.step <= 0:
            raise ValueError(f"{where}: {what} slice step must be positive, got {sel.step}")
        return sel
    idx = np.atleast_1d(np.asarray(sel))
    if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
        raise ValueError(f"{where}: {what} must be None, an int, a slice or a sequence of ints, got {sel!r}")
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise IndexError(f"{where}: {what} {idx.tolist()} out of range [0, {n})")
    return idx.astype(np.int64)


class CaptureStore:
    """An open capture store (:func:`open_capture_store`): the manifest, rig and
    cameras in memory; radiance and mask read on demand, chunk by chunk.

    Attributes:
        path, shape ``(V, L, P, C)``, dtype, chunks, n_views, n_lights,
        n_samples, n_channels, sample_shape ``(H, W)``, channels, half,
        has_valid, rig (rig.json's dict), cameras (cameras.json's list),
        metadata (the capture's metadata), generation.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"{self.path}: no such capture store")
        self.manifest_path = self.path / MARKER
        where = str(self.manifest_path)
        if not self.manifest_path.is_file():
            raise CaptureStoreError(f"{self.path}: no {MARKER}, so not a complete capture store (an interrupted or "
                                    "unfinished write, or not a relight store)")
        info = read_json(self.manifest_path, "a capture store's manifest")
        if not isinstance(info, Mapping) or info.get("format") != FORMAT:
            fmt = info.get("format") if isinstance(info, Mapping) else None
            raise CaptureStoreError(f"{where}: not a relight capture store (format {fmt!r})")
        if info.get("version", 0) > VERSION:
            raise CaptureStoreError(f"{where}: format version {info.get('version')} is newer than this reader "
                                    f"({VERSION})")
        try:
            shape = tuple(int(s) for s in info["shape"])
            self.sample_shape = tuple(int(s) for s in info["sample_shape"])
            self.channels = [str(c) for c in info["channels"]]
            dtype = _DTYPES[info["dtype"]]
            self.generation = str(info["generation"])
            arrays, files = dict(info["arrays"]), dict(info["files"])
            version = int(info.get("version", 1))
            digests = info.get("chunk_digests") if version >= 2 else None
            if version >= 2 and not (isinstance(digests, Mapping) and digests.get("digest") == DIGEST
                                     and all(isinstance(digests.get(k), Mapping) for k in _ARRAYS)):
                raise ValueError(f"field 'chunk_digests' must hold a {DIGEST} digest per chunk of "
                                 f"{sorted(_ARRAYS)}")
        except (KeyError, TypeError, ValueError) as err:
            raise CaptureStoreError(f"{where}: missing or bad field ({err!r})") from None
        if digests is None:
            warnings.warn(f"{self.path}: a version {version} capture store, written before chunk digests: a missing "
                          "or undecodable chunk is still refused, but a damaged chunk that still decodes cannot be "
                          "detected. Rewrite it with this version (relight convert it to a folder and back)",
                          UserWarning, stacklevel=3)
        if len(shape) != 4 or min(shape) < 1:
            raise CaptureStoreError(f"{where}: field 'shape' must be [V, L, P, C] of positive sizes, got {list(shape)}")
        self.shape = shape
        self.n_views, self.n_lights, self.n_samples, self.n_channels = shape
        self.dtype = np.dtype(dtype)
        if len(self.sample_shape) != 2 or self.sample_shape[0] * self.sample_shape[1] != self.n_samples:
            raise CaptureStoreError(f"{where}: sample_shape {list(self.sample_shape)} does not hold "
                                    f"{self.n_samples} samples")
        if len(self.channels) != self.n_channels:
            raise CaptureStoreError(f"{where}: {len(self.channels)} channel names for {self.n_channels} channels")
        self.half = bool(info.get("half", self.dtype == np.float16))
        self.has_valid = bool(info.get("has_valid", True))
        self.metadata = dict(info.get("metadata") or {})
        if (self.path / RESULT_MANIFEST).is_file():
            # Inside a command's result set (relight simulate --out X.zarr): the manifest, rig and cameras must be
            # the files that set committed (its manifest lists them; the chunks are this manifest's generation's).
            with set_refusal_as(self.path, CaptureStoreError):
                rs = open_result_set(self.path)
                rs.check([n for n in (MARKER, *(str(files.get(k)) for k in _FILES)) if n in rs.files])
        self._open_parts(arrays, files, where, digests)
        self.chunks = tuple(int(c) for c in self._radiance.chunks)

    def _open_parts(self, arrays: dict, files: dict, where: str, digests: Mapping | None) -> None:
        """Read rig.json and cameras.json and open the two arrays, checking each against the manifest; the
        arrays read through a :class:`ChecksummedStore`, so a chunk file that is missing, or (with the
        version 2 ``digests``) differs from what was written, is refused, never read as zeros."""
        import zarr

        shape = self.shape
        paths = {k: _inside(self.path, arrays.get(k), where, f"arrays.{k}") for k in _ARRAYS}
        paths |= {k: _inside(self.path, files.get(k), where, f"files.{k}") for k in _FILES}
        rig_path, cam_path = paths["rig"], paths["cameras"]
        self.rig = read_json(rig_path, "a capture store needs its rig.json")
        self._rig_where = str(rig_path)
        try:
            n_rig = _rig_light_count(self.rig, rig_path)
        except ImageFormatError as err:
            raise CaptureStoreError(str(err)) from None
        if n_rig != self.n_lights:
            raise CaptureStoreError(f"{rig_path}: {n_rig} lights in the rig but {where} declares {self.n_lights}")
        self.cameras = read_json(cam_path, "a capture store needs its cameras.json")
        self._cam_where = str(cam_path)
        if not isinstance(self.cameras, list) or len(self.cameras) != self.n_views:
            n = len(self.cameras) if isinstance(self.cameras, list) else "no list of"
            raise CaptureStoreError(f"{cam_path}: {n} cameras but {where} declares {self.n_views} views")
        rel = {k: Path(os.path.relpath(paths[k], self.path.resolve())).as_posix() for k in _ARRAYS}
        expected = None if digests is None else {f"{rel[k]}/{key}": str(d) for k in _ARRAYS
                                                 for key, d in dict(digests[k]).items()}
        try:
            store = ChecksummedStore(self.path, read_only=True, digests=expected, arrays=tuple(rel.values()))
            root = zarr.open_group(store=store, mode="r", zarr_format=3)
            self._radiance = root[rel["radiance"]]
            self._mask = root[rel["mask"]]
        except (KeyError, FileNotFoundError, ValueError) as err:
            raise CaptureStoreError(f"{self.path}: the Zarr group or its arrays cannot be opened ({err!r})") from None
        attrs = dict(root.attrs).get("relight", {})
        if not isinstance(attrs, Mapping) or attrs.get("generation") != self.generation:
            raise CaptureStoreError(f"{self.path}: zarr.json's generation does not match {MARKER}'s: the arrays and "
                                    "the manifest come from different writes")
        for name, arr, want, dt in (("radiance", self._radiance, shape, self.dtype),
                                    ("mask", self._mask, shape[:3], np.dtype(bool))):
            if tuple(arr.shape) != tuple(want):
                raise CaptureStoreError(f"{self.path}: array '{name}' has shape {tuple(arr.shape)}, "
                                        f"{MARKER} declares {tuple(want)}")
            if np.dtype(arr.dtype) != dt:
                raise CaptureStoreError(f"{self.path}: array '{name}' is {np.dtype(arr.dtype)}, expected {dt}")
            grid = [-(-s // c) for s, c in zip(arr.shape, arr.chunks, strict=True)]
            if expected is not None and not set(chunk_keys(rel[name], grid)) <= expected.keys():
                raise CaptureStoreError(f"{where}: field 'chunk_digests' does not cover every chunk of array "
                                        f"'{name}' ({int(np.prod(grid))} chunks)")

    def __repr__(self) -> str:
        return f"CaptureStore({str(self.path)!r}, shape={self.shape}, dtype={self.dtype.name}, chunks={self.chunks})"

    def _damaged(self, err: Exception) -> Exception:
        """A read's failure as the error to raise: a missing or damaged chunk (:class:`DamagedChunkError`) or a
        chunk the codec cannot decode (a truncated file of a version 1 store) is a CaptureStoreError naming the
        store and what is wrong with it; anything else as it is."""
        if isinstance(err, DamagedChunkError):
            return CaptureStoreError(f"{self.path}: damaged store: {err}; it is not read as zeros. Rewrite it "
                                     "(relight convert from its source, or re-run the command that made it)")
        if isinstance(err, (RuntimeError, ValueError)) and not isinstance(err, ImageFormatError):
            return CaptureStoreError(f"{self.path}: damaged store: a chunk cannot be decoded ({err}). Rewrite it "
                                     "(relight convert from its source, or re-run the command that made it)")
        return err

    def _check_generation(self) -> None:
        try:
            info = read_json(self.manifest_path)
            gen = info.get("generation") if isinstance(info, Mapping) else None
        except (OSError, ValueError):
            gen = None
        if gen != self.generation:
            raise StoreChangedError(f"{self.path}: the store was replaced or removed while open; reopen it")

    def stage_rig(self) -> stage.Rig:
        """rig.json as a ``stage.Rig`` (``stage.rig_from_dict``; ValueError naming the file and field)."""
        return stage.rig_from_dict(self.rig, self._rig_where)

    def stage_cameras(self) -> tuple[stage.Camera, ...]:
        """cameras.json as ``stage.Camera`` s (``stage.camera_from_dict``, each entry)."""
        return tuple(stage.camera_from_dict(c, f"{self._cam_where}: camera {i}") for i, c in enumerate(self.cameras))

    @property
    def nbytes(self) -> int:
        """Uncompressed size of radiance and mask, bytes."""
        return int(np.prod(self.shape)) * self.dtype.itemsize + int(np.prod(self.shape[:3]))

    def read(self, views=None, lights=None, samples=None, dtype=None) -> tuple[np.ndarray, np.ndarray]:
        """``(radiance [V', L', P', C], mask [V', L', P'])`` as NumPy arrays for
        the selected views, lights and samples (each None = all, an int, a
        slice or a sequence of ints; the axes are kept). Reads only the chunks
        the selection touches: memory is the result plus the chunks in flight.
        ``dtype`` casts the radiance (default: the stored dtype). Raises
        StoreChangedError if the store was replaced during the read."""
        sel = (_selector(views, self.n_views, "views", self.path),
               _selector(lights, self.n_lights, "lights", self.path),
               _selector(samples, self.n_samples, "samples", self.path))
        self._check_generation()
        try:
            rad = np.asarray(self._radiance.get_orthogonal_selection((*sel, slice(None))))
            msk = np.asarray(self._mask.get_orthogonal_selection(sel))
        except Exception as err:
            self._check_generation()  # a replaced store can fail to decode: say so, not why
            raise self._damaged(err) from err
        self._check_generation()
        if dtype is not None:
            rad = rad.astype(dtype, copy=False)
        return rad, msk.astype(bool, copy=False)

    def read_mask(self, views=None, lights=None, samples=None) -> np.ndarray:
        """The mask [V', L', P'] (bool) of :meth:`read`'s selection, reading only the
        mask array (no radiance chunk is decoded: the fitter's counting pass, texel
        coverage). Raises StoreChangedError if the store was replaced during the read."""
        sel = (_selector(views, self.n_views, "views", self.path),
               _selector(lights, self.n_lights, "lights", self.path),
               _selector(samples, self.n_samples, "samples", self.path))
        self._check_generation()
        try:
            msk = np.asarray(self._mask.get_orthogonal_selection(sel))
        except Exception as err:
            self._check_generation()
            raise self._damaged(err) from err
        self._check_generation()
        return msk.astype(bool, copy=False)

    def iter_sample_chunks(self, n: int | None = None, dtype=None
                           ) -> Iterator[tuple[slice, np.ndarray, np.ndarray]]:
        """Yield ``(sample slice, radiance [V, L, n', C], mask [V, L, n'])`` over
        consecutive blocks of ``n`` samples (default: the store's sample chunk;
        a multiple of it reads each chunk once), covering every sample exactly
        once (the last block may be shorter). A consumer holds one block."""
        n = self.chunks[2] if n is None else int(n)
        if n < 1:
            raise ValueError(f"{self.path}: n must be a positive sample count, got {n}")
        for s in range(0, self.n_samples, n):
            sl = slice(s, min(s + n, self.n_samples))
            # No local keeps the block: once the consumer drops it, reading the next needs no room for two.
            yield (sl, *self.read(samples=sl, dtype=dtype))

    def gather_samples(self, index, dtype=np.float32, progress: stage.Progress | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
        """``(radiance [V, L, len(index), C], mask [V, L, len(index)])`` at the
        samples ``index`` (ints), read one sample chunk at a time (chunks with
        none of them are skipped). ``progress`` counts the sample chunks, phase
        "read capture"."""
        idx = np.asarray(index, np.int64).reshape(-1)
        if idx.size and (idx.min() < 0 or idx.max() >= self.n_samples):
            raise IndexError(f"{self.path}: sample index out of range [0, {self.n_samples})")
        V, L, _, C = self.shape
        rad = np.zeros((V, L, idx.size, C), dtype)
        msk = np.zeros((V, L, idx.size), bool)
        n = self.chunks[2]
        bar = stage.Phase(progress, "read capture", -(-self.n_samples // n))
        for s in range(0, self.n_samples, n):
            e = min(s + n, self.n_samples)
            here = np.nonzero((idx >= s) & (idx < e))[0]
            if here.size:
                r, m = self.read(samples=slice(s, e))
                rad[:, :, here] = r[:, :, idx[here] - s]
                msk[:, :, here] = m[:, :, idx[here] - s]
            bar.advance(1)
        return rad, msk

    def to_capture(self, max_bytes: int = 8 << 30) -> stage.Capture:
        """The whole store as a ``stage.Capture`` (stored dtype; no sensor), for
        stores that fit in memory: ValueError above ``max_bytes`` (uncompressed;
        stream with :meth:`iter_sample_chunks` instead)."""
        if self.nbytes > max_bytes:
            raise ValueError(f"{self.path}: {self.nbytes / 2**30:.2f} GiB uncompressed is over max_bytes "
                             f"({max_bytes / 2**30:.2f} GiB); read it in chunks with iter_sample_chunks")
        rad, msk = self.read()
        return stage.Capture(radiance=jnp.asarray(rad), mask=jnp.asarray(msk), rig=self.stage_rig(),
                             cameras=self.stage_cameras())


def open_capture_store(path: str | os.PathLike) -> CaptureStore:
    """Open a capture store (reads the manifest, rig and cameras; no pixels).

    Raises FileNotFoundError for a missing folder and CaptureStoreError (an
    ImageFormatError) naming the path for a folder without the completion
    marker, a manifest whose shape, dtype or generation disagree with the
    arrays, rig or cameras, or a manifest path that leaves the store."""
    return CaptureStore(path)


def capture_folder_to_store(folder: str | os.PathLike, store_path: str | os.PathLike, *,
                            chunks: Sequence[int] | None = None, progress: stage.Progress | None = None) -> Path:
    """Convert a capture folder (relight.io.write_capture's layout) to a capture
    store, reading one EXR at a time: memory is the chunks being filled (one
    view's Lc images with the default chunks), never the capture. The radiance
    keeps its stored precision (half folders give a float16 store);
    capture.json's metadata, sample_shape, channels and has_valid, and
    rig.json / cameras.json are carried over as they are. ``progress``
    counts images, phase "convert". Returns the store's path.

    Raises as :func:`relight.io.open_capture` (naming the file), and
    ImageFormatError when capture.json's ``files`` template points outside
    the folder."""
    folder = Path(folder)
    reader = open_capture(folder)
    V, L, P, C = reader.shape
    # open_capture has checked that every image path stays inside the folder.
    rig = read_json(folder / "rig.json")  # as written: the reader turns lists into arrays
    first, _ = reader.read_image(0, 0, dtype=None)
    dtype = np.float16 if reader.half and first.dtype == np.float16 else np.float32
    bar = stage.Phase(progress, "convert", V * L)
    with CaptureStoreWriter(store_path, reader.shape, dtype, rig, reader.cameras, reader.metadata, chunks,
                            sample_shape=reader.sample_shape, channels=reader.channels,
                            has_valid=reader.has_valid) as w:
        for v in range(V):
            for light in range(L):
                rad, valid = reader.read_image(v, light, dtype=None)
                if rad.dtype.itemsize > w.dtype.itemsize:
                    raise ImageFormatError(f"{reader.path(v, light)}: {rad.dtype} radiance in a half capture "
                                           "(capture.json says half); it would lose precision")
                w.write(v, light, slice(None), rad[None], None if valid is None else valid[None])
                bar.advance(1)
    return Path(store_path)


def store_to_capture_folder(store_path: str | os.PathLike, folder: str | os.PathLike, *,
                            progress: stage.Progress | None = None) -> Path:
    """Convert a capture store back to a capture folder (the layout
    relight.io.open_capture reads: one EXR per view and light, rig.json,
    cameras.json, capture.json with the store's metadata), atomically (the
    folder is swapped into place; an existing capture folder is replaced).
    Reads one view and light chunk at a time. ``progress`` counts images,
    phase "convert". Returns the folder's path."""
    store = open_capture_store(store_path)
    folder = Path(folder)
    V, L, _, _ = store.shape
    cl = store.chunks[1]
    bar = stage.Phase(progress, "convert", V * L)
    with _atomic_folder(folder) as tmp:
        for v in range(V):
            for l0 in range(0, L, cl):
                rad, msk = store.read(views=v, lights=slice(l0, min(l0 + cl, L)))
                for j in range(rad.shape[1]):
                    light = l0 + j
                    path = tmp / _FOLDER_FILES.format(view=v, light=light)
                    path.parent.mkdir(parents=True, exist_ok=True)
                    chans = {n: rad[0, j, :, i].reshape(store.sample_shape) for i, n in enumerate(store.channels)}
                    if store.has_valid:
                        chans["valid"] = msk[0, j].reshape(store.sample_shape).astype(np.float16)
                    write_exr_channels(path, chans, header={"relight.view": v, "relight.light": light},
                                       half=store.half)
                    bar.advance(1)
        write_json(tmp / "rig.json", store.rig, indent=1)
        write_json(tmp / "cameras.json", store.cameras, indent=1)
        write_json(tmp / "capture.json",
                   {"format": _FOLDER_FORMAT, "version": _FOLDER_VERSION, "n_views": V, "n_lights": L,
                    "sample_shape": list(store.sample_shape), "channels": store.channels, "half": store.half,
                    "has_valid": store.has_valid, "files": _FOLDER_FILES, "metadata": store.metadata}, indent=1)
    return folder
