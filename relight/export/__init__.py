"""Exporters: a fitted texture set as a scene another renderer reads (Mitsuba 3's
XML, with the environment map resampled so that Mitsuba's lookups return
relight's pixels). See docs/relight_io.md ("Exporters") and docs/cli.md."""

from ._mitsuba import mitsuba_envmap as mitsuba_envmap
from ._mitsuba import write_mitsuba_scene as write_mitsuba_scene

__all__ = ["mitsuba_envmap", "write_mitsuba_scene"]
