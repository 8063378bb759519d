"""The environment map shipped with the package (in ``relight/data``)."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["bundled_envmap_path"]


def bundled_envmap_path() -> Path:
    """The bundled CC0 'Venice Sunset' map (Poly Haven), a 1024x512 lat-long
    Radiance HDR; the default ``--envmap`` of the ``relight`` commands. See
    relight/data/ATTRIBUTION.md."""
    return Path(str(resources.files("relight.data").joinpath("venice_sunset_1k.hdr")))
