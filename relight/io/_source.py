"""One read interface for every capture a fit reads: the ``CaptureSource`` protocol.

A capture source holds the radiance [V, L, P, C] and validity mask [V, L, P] of an OLAT capture
(views x lights x samples x channels) and hands out any selection of them, so a consumer (the fitter)
reads a block of samples at a time and never needs the whole stack in memory. Implemented by
``relight.io.CaptureStore`` (a Zarr store), ``relight.io.CaptureReader`` (a capture folder),
``relight.io.SampleSubset`` (some samples of either) and, through :func:`capture_source`, a
``stage.Capture`` in memory (``ArraySource``). Photo and DiLiGenT captures reach the fitter as a
``stage.Capture`` (``photos_to_texels``, ``diligent_capture``).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

import stage

__all__ = ["ArraySource", "CaptureSource", "capture_source", "valid_counts"]


@runtime_checkable
class CaptureSource(Protocol):
    """What a fit reads a capture through.

    **Attributes:**

    - ``shape``: ``(V, L, P, C)``: views, lights, samples, channels.

    **Methods:**

    - ``stage_rig()``: the capture's ``stage.Rig`` (its L lights).
    - ``stage_cameras()``: its V ``stage.Camera`` s, as a tuple.
    - ``read(views=None, lights=None, samples=None)``: ``(radiance [V', L', P', C],
      mask [V', L', P'] bool)`` as NumPy arrays; each selector None (all), an int, a slice or a
      sequence of ints, every axis kept. An observation without a stored mask is valid.
    - ``read_mask(views=None, lights=None, samples=None)``: the mask of the same selection,
      reading no more than it needs (a store decodes no radiance).

    Sources may restrict the selections they take (``SampleSubset``: all views and lights, a slice
    of samples); every source takes ``samples=slice(start, stop)`` with the other two None, which
    is all a fit asks for.
    """

    shape: tuple[int, int, int, int]

    def stage_rig(self) -> stage.Rig: ...

    def stage_cameras(self) -> tuple[stage.Camera, ...]: ...

    def read(self, views=None, lights=None, samples=None) -> tuple[np.ndarray, np.ndarray]: ...

    def read_mask(self, views=None, lights=None, samples=None) -> np.ndarray: ...


def _select(a, axis: int, sel):
    """``a`` with one axis selected by None, an int, a slice or a sequence of ints (the axis kept)."""
    if sel is None:
        return a
    key = [slice(None)] * axis
    if isinstance(sel, slice):
        return a[(*key, sel)]
    return np.take(np.asarray(a), np.atleast_1d(np.asarray(sel, np.int64)), axis=axis)


class ArraySource:
    """A ``stage.Capture`` (radiance and mask already in memory) as a :class:`CaptureSource`.

    Args:
        capture: the capture; its arrays are sliced, not copied, until read.
    """

    def __init__(self, capture: stage.Capture):
        self.capture = capture
        self.shape = tuple(int(s) for s in capture.radiance.shape)

    def __repr__(self) -> str:
        return f"ArraySource(shape={self.shape})"

    def stage_rig(self) -> stage.Rig:
        return self.capture.rig

    def stage_cameras(self) -> tuple[stage.Camera, ...]:
        return tuple(self.capture.cameras)

    def read(self, views=None, lights=None, samples=None) -> tuple[np.ndarray, np.ndarray]:
        rad, mask = self.capture.radiance, self.capture.mask
        for axis, sel in enumerate((views, lights, samples)):
            rad, mask = _select(rad, axis, sel), _select(mask, axis, sel)
        return np.asarray(rad), np.asarray(mask, bool)

    def read_mask(self, views=None, lights=None, samples=None) -> np.ndarray:
        mask = self.capture.mask
        for axis, sel in enumerate((views, lights, samples)):
            mask = _select(mask, axis, sel)
        return np.asarray(mask, bool)


def capture_source(capture) -> CaptureSource:
    """``capture`` as a :class:`CaptureSource`.

    Args:
        capture: a ``stage.Capture`` (wrapped in :class:`ArraySource`) or a capture source
            (``relight.io.open_capture_store``, ``relight.io.open_capture``, a ``SampleSubset``),
            returned as it is.

    Returns:
        The source.

    Raises TypeError naming ``capture`` if it is neither.
    """
    if isinstance(capture, stage.Capture):
        return ArraySource(capture)
    if isinstance(capture, CaptureSource):
        return capture
    raise TypeError("capture must be a stage.Capture or a relight.io.CaptureSource (shape (V, L, P, C), "
                    "stage_rig(), stage_cameras(), read(views=, lights=, samples=) -> (radiance, mask), "
                    "read_mask(...)): relight.io.open_capture_store, relight.io.open_capture or a SampleSubset; "
                    f"got {type(capture).__name__}")


def valid_counts(source: CaptureSource, block: int) -> np.ndarray:
    """Valid observations per sample (views x lights), reading the mask ``block`` samples at a time.

    Args:
        source: a :class:`CaptureSource`.
        block: samples per read (bounds the memory to one block's mask).

    Returns:
        int64 [P].
    """
    P = int(source.shape[2])
    out = np.zeros(P, np.int64)
    for s in range(0, P, block):
        e = min(s + block, P)
        out[s:e] = np.sum(source.read_mask(samples=slice(s, e)), axis=(0, 1))
    return out
