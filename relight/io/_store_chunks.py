"""Chunk checksums of a capture store (format version 2): the writer records a digest of every chunk file as
Zarr writes it, the manifest keeps them, and the reader checks each chunk file against its digest as Zarr fetches
it, before it is decoded.

Why: Zarr reads a missing chunk file as the array's fill value. A store that lost one radiance chunk (a partial
copy, a full disk, a deleted file) would be fitted as black pixels, and a truncated chunk surfaces as a raw codec
error. A store's chunks are all on disk (``write_empty_chunks``), so a missing file is damage, never zeros; a
digest catches a file that is there but not the one written.

The digest is BLAKE2b with an 8-byte output over the chunk file's bytes (compressed, as stored): it detects
damage, it is not a signature. Version 1 stores (no digests) are still read; their chunks are checked for
presence only.
"""

from __future__ import annotations

import hashlib

from zarr.storage import LocalStore

DIGEST = "blake2b-64"


def chunk_digest(data: bytes) -> str:
    """The hex digest recorded for a chunk file's bytes (``DIGEST``)."""
    return hashlib.blake2b(data, digest_size=8).hexdigest()


def chunk_keys(array: str, grid) -> list[str]:
    """The chunk keys of ``array`` with chunk grid ``grid`` (chunks per axis), as Zarr v3's default
    encoding names them (``<array>/c/i/j/...``), in C order."""
    import numpy as np

    return [f"{array}/c/" + "/".join(str(int(i)) for i in idx) for idx in np.ndindex(*(int(g) for g in grid))]


class DamagedChunkError(Exception):
    """A chunk file that is missing or does not match its recorded digest (raised inside Zarr's read; the
    capture store reader turns it into a CaptureStoreError naming the store)."""


class ChecksummedStore(LocalStore):
    """A Zarr ``LocalStore`` that records the digest of every chunk file it writes (``digests``, key -> hex) and,
    given the recorded digests, refuses on read a chunk file that is missing or differs (:class:`DamagedChunkError`).

    Args:
        root: the store folder.
        read_only: as ``LocalStore``.
        digests: for reading: the recorded ``{key: hex}`` of every chunk (version 2 stores), checked on each read;
            None: chunks are only required to exist (version 1).
        arrays: the array names whose chunks are checked (others pass through).
    """

    def __init__(self, root, *, read_only: bool = False, digests: dict | None = None, arrays=("radiance", "mask")):
        super().__init__(root, read_only=read_only)
        self.expected = digests
        self.digests: dict[str, str] = {}
        self.arrays = tuple(arrays)

    def with_read_only(self, read_only: bool = False):
        twin = type(self)(self.root, read_only=read_only, digests=self.expected, arrays=self.arrays)
        twin.digests = self.digests
        return twin

    def _is_chunk(self, key: str) -> bool:
        return any(key.startswith(f"{a}/c/") for a in self.arrays)

    async def set(self, key: str, value) -> None:
        await super().set(key, value)
        if self._is_chunk(key):
            self.digests[key] = chunk_digest(value.to_bytes())

    async def get(self, key: str, prototype=None, byte_range=None):
        value = await super().get(key, prototype, byte_range)
        if not self._is_chunk(key):
            return value
        if value is None:
            raise DamagedChunkError(f"chunk file {key} is missing")
        if self.expected is not None and byte_range is None:
            want = self.expected.get(key)
            if want is None:
                raise DamagedChunkError(f"chunk file {key} is not in the manifest's digests")
            if chunk_digest(value.to_bytes()) != want:
                raise DamagedChunkError(f"chunk file {key} does not match its recorded digest (truncated, "
                                        "overwritten or corrupted)")
        return value
