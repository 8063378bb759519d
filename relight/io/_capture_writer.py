"""Capture writers for ``stage.simulate_into``: the capture folder held in memory and
written whole, and the store's block geometry."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from ._capture import write_capture
from ._store import LIGHT_CHUNK, default_chunks


class CaptureFolderWriter:
    """A capture folder written through the ``stage.CaptureWriter`` protocol (a context manager).

    ``write(view, lights, samples, radiance [nL, nS, C], mask [nL, nS])`` fills
    a float32 capture held in memory (``radiance`` [V, L, S, C] and ``valid``
    [V, L, S], readable as attributes); ``close()`` (leaving the ``with`` block
    normally) writes it with :func:`write_capture`; leaving it by an exception
    writes nothing. For captures larger than memory use ``CaptureStoreWriter``,
    which takes the same arguments.

    Args:
        path: the capture folder to write.
        shape: ``(V, L, S, C)``.
        dtype: float32, or float16 to store half floats (``write_capture``'s ``half``).
        rig: a ``stage.Rig`` or rig dict with L lights.
        cameras: V ``stage.Camera`` s or camera dicts.
        metadata: JSON-able dict (capture.json's metadata).
        sample_shape: ``(H, W)`` with ``H * W = S`` (default ``(1, S)``).
        channels: channel names (default R, G, B for C = 3, Y for C = 1).
    """

    def __init__(self, path: str | os.PathLike, shape: Sequence[int], dtype=np.float32, rig=None, cameras=None,
                 metadata: Mapping | None = None, *, sample_shape: Sequence[int] | None = None,
                 channels: Sequence[str] | None = None):
        self.path = Path(path)
        shape = tuple(int(s) for s in shape)
        if len(shape) != 4 or min(shape) < 1:
            raise ValueError(f"{self.path}: shape must be (V, L, S, C) of positive sizes, got {shape}")
        if np.dtype(dtype) not in (np.float32, np.float16):
            raise ValueError(f"{self.path}: dtype must be float32 or float16, got {np.dtype(dtype).name}")
        if rig is None:
            raise ValueError(f"{self.path}: rig is required (a stage.Rig or a rig dict)")
        self.shape, self.half = shape, np.dtype(dtype) == np.float16
        self.rig, self.cameras, self.metadata, self.channels = rig, cameras, metadata, channels
        self.sample_shape = None if sample_shape is None else tuple(int(s) for s in sample_shape)
        self.radiance = np.zeros(shape, np.float32)
        self.valid = np.zeros(shape[:3], bool)

    def __enter__(self) -> CaptureFolderWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()

    def write(self, view: int, lights: slice, samples: slice, radiance, mask) -> None:
        """Store ``radiance`` [nL, nS, C] and ``mask`` [nL, nS] at (view, lights, samples)."""
        self.radiance[view, lights, samples] = radiance
        self.valid[view, lights, samples] = mask

    def close(self) -> Path:
        """Write the capture folder (atomically, ``write_capture``); returns its path."""
        write_capture(self.path, self.radiance, self.rig, self.cameras, valid=self.valid, metadata=self.metadata,
                      sample_shape=self.sample_shape, half=self.half, channels=self.channels)
        return self.path


def store_blocks(n_samples: int, block: int, channels: int, dtype) -> tuple[int, int]:
    """The block and the sample chunk of a capture store streamed block by block.

    Args:
        n_samples: the samples of the grid (H * W).
        block: the wanted grid samples per block (>= 1).
        channels: C.
        dtype: the store's radiance dtype.

    Returns:
        (samples per block, the store's sample chunk): the chunk is
        :func:`default_chunks`'s (about 2 MiB of ``LIGHT_CHUNK`` lights) or the
        largest power of two <= ``block`` if smaller, and the block is rounded down
        to a multiple of it, so that every block writes whole chunks.
    """
    pc = default_chunks((1, LIGHT_CHUNK, int(n_samples), int(channels)), dtype)[2]
    pc = max(1, min(pc, 1 << int(math.floor(math.log2(max(1, int(block)))))))
    return max(pc, (int(block) // pc) * pc), pc
