"""The process's memory probes: its peak resident set and glibc's ``malloc_trim``."""

from __future__ import annotations

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
    of bytes a texel) are freed but kept by glibc; trimming stops them staying resident under the phases
    that follow.

    Returns:
        None.
    """
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        pass


def mark() -> float | None:
    """The peak resident set so far (:func:`peak_rss_mib`), then :func:`release_freed_memory`.

    Returns:
        MiB, or None where the platform does not say.
    """
    peak = peak_rss_mib()
    release_freed_memory()
    return peak
