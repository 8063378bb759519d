"""The process's memory probes: its peak resident set and glibc's ``malloc_trim``.

Streaming work (a light chunk of photographs, a block of texels) frees arrays of tens of MiB in a loop; glibc
keeps freed heap for reuse, and past its dynamic mmap threshold (which grows to the largest block freed, up to
32 MiB) such blocks land on the heap, so the process's resident set climbs with every chunk although what is
alive does not. Trimming after each chunk keeps the resident set at what the chunk sizes need.
"""

from __future__ import annotations

import functools

__all__ = ["peak_rss_mib", "release_freed_memory"]


def peak_rss_mib() -> float | None:
    """The process's peak resident set so far.

    Returns:
        MiB (Linux's ``ru_maxrss`` is in KiB), or None where the platform does not say.
    """
    try:
        import resource

        return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
    except (ImportError, OSError):  # pragma: no cover - not Linux / macOS
        return None


def release_freed_memory() -> None:
    """Hand freed heap back to the system (glibc's ``malloc_trim``; nothing elsewhere).

    A texel grid's temporaries (``stage.texel_samples``, the camera visibility of the whole grid: hundreds
    of bytes a texel) and a streaming loop's chunks are freed but kept by glibc; trimming stops them staying
    resident under the phases and chunks that follow (a few ms on a heap of a GiB).

    Returns:
        None.
    """
    trim = _malloc_trim()
    if trim is not None:
        trim(0)


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or None where the C library is not glibc."""
    try:
        import ctypes

        return ctypes.CDLL("libc.so.6").malloc_trim
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        return None
