"""Simulated captures written whole: what ``relight simulate`` does as one library call.

``simulate_texel_capture`` simulates an OLAT capture of the demo's skin-like material (with optional
subsurface scattering, :class:`MeanFreePath`) on a mesh's texel grid and writes it as a capture folder or a
capture store with its ground truth; ``simulate_photo_capture`` writes the camera-space photographs as a
photo capture. The formats are ``relight.io``'s; ``peak_rss_mib`` and ``release_freed_memory`` (``stage``'s) are the
memory probes the texel pipeline records after each phase. See docs/relight_simulation.md."""

from stage import peak_rss_mib as peak_rss_mib
from stage import release_freed_memory as release_freed_memory

from ._capture import MeanFreePath as MeanFreePath
from ._capture import SimulatedCapture as SimulatedCapture
from ._photo import simulate_photo_capture as simulate_photo_capture
from ._texel import simulate_texel_capture as simulate_texel_capture

__all__ = [
    "MeanFreePath",
    "SimulatedCapture",
    "peak_rss_mib",
    "release_freed_memory",
    "simulate_photo_capture",
    "simulate_texel_capture",
]
