"""Render methods as typed objects: ``Rig``, ``Dense``, ``Lights``, ``Fast``, ``Reference``.

Each is a small final equinox Module holding one method's settings, checked
when it is built (a ValueError naming the setting). ``render_samples``,
``render_view`` and ``turntable`` take one as ``method=``, alongside the string
names (``"rig"``, ``"dense"``, ``"lights"``, ``"fast"``, ``"reference"``, the CLI's
spellings), which map to the defaults; string names with method-specific
keyword settings (``method="dense", resolution=16``) keep working and build
the same object. The settings shared by every method (``chunk``, ``eta``,
``operator``, ``rotation``, ``dtype``) stay keyword arguments of the call.

* ``Rig``: ``rig`` (None: ``stage.light_stage_x()``), ``weights`` ("voronoi"
  or "barycentric"), ``supersample`` (1) -- the environment sampled at a rig's
  lights (Debevec et al. 2000), lit by the rig's own near-field lights.
* ``Dense``: ``rows`` (32; keyword ``resolution``) -- the midpoint rule over
  the map area-averaged to rows x 2 rows pixels, ray-cast shadows.
* ``Lights``: ``lights`` (256) -- the environment cut into regions of equal
  energy (median cut, Debevec 2005), each a distant light with ray-cast shadows.
* ``Fast``: ``levels`` (7), ``prefilter_rows`` (128), ``prefilter_samples``
  (64), ``ao_rays`` (64), ``lut_size`` (32) -- SH irradiance (Ramamoorthi &
  Hanrahan 2001) + split-sum specular (Karis 2013) + ambient occlusion.
* ``Reference``: ``samples`` (256), ``env_fraction`` (0.5), ``heuristic``
  ("power" or "balance") -- Monte Carlo with multiple importance sampling
  (Veach & Guibas 1995).
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import numpy as np

import stage

from . import _fast as fast

__all__ = ["AbstractMethod", "Dense", "Fast", "Lights", "Reference", "Rig", "resolve_method"]


def _int_at_least(owner: str, name: str, value, lo: int, alias: str | None = None) -> None:
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < lo:
        label = f"{name!r}" if alias is None else f"{name!r} (keyword {alias!r})"
        raise ValueError(f"method {owner!r}: setting {label} must be an integer >= {lo}, got {value!r}")


class AbstractMethod(eqx.Module):
    """A render method and its settings. ``name`` is the string spelling;
    ``settings()`` the flat settings dict the renderer reads; ``KEYWORDS``
    maps the keyword settings of the string spelling to field names."""

    name: ClassVar[str]
    KEYWORDS: ClassVar[dict[str, str]]

    def settings(self) -> dict:
        """The settings under their keyword names (``resolution`` for Dense's rows)."""
        inv = {field: kw for kw, field in self.KEYWORDS.items()}
        return {inv[f]: getattr(self, f) for f in inv}


class Rig(AbstractMethod):
    """The environment sampled at a light rig's lights with
    ``relight.envmap.light_weights`` (Voronoi cells; or barycentric), each light
    shading through stage's OLAT forward model with its near-field falloff:
    what an OLAT capture supports (Debevec et al. 2000). ``rig``: a
    ``stage.Rig`` (None: ``stage.light_stage_x()``); ``supersample`` of the
    Voronoi weights."""

    rig: stage.Rig | None = None
    weights: str = "voronoi"
    supersample: int = 1

    name: ClassVar[str] = "rig"
    KEYWORDS: ClassVar[dict[str, str]] = {"rig": "rig", "weights": "weights", "supersample": "supersample"}

    def __check_init__(self):
        _int_at_least("rig", "supersample", self.supersample, 1)
        if self.weights not in ("voronoi", "barycentric"):
            raise ValueError(f"method 'rig': weights must be 'voronoi' or 'barycentric', got {self.weights!r}")
        if self.rig is not None and not isinstance(self.rig, stage.Rig):
            raise ValueError(f"method 'rig': rig must be a stage.Rig, got {type(self.rig).__name__}")


class Dense(AbstractMethod):
    """The midpoint rule over the environment area-resampled to ``rows`` x
    2 ``rows`` pixels, each a distant light with ray-cast visibility
    (converges to the exact integral as ``rows`` grows)."""

    rows: int = 32

    name: ClassVar[str] = "dense"
    KEYWORDS: ClassVar[dict[str, str]] = {"resolution": "rows"}

    def __check_init__(self):
        _int_at_least("dense", "rows", self.rows, 2, alias="resolution")


class Lights(AbstractMethod):
    """The environment cut by median cut (Debevec 2005) into ``lights``
    regions of equal energy, each a distant light at its energy centroid
    carrying the region's exact integral, with ray-cast visibility per light
    (``lights`` rays per sample). Converges to the midpoint rule of the map at
    its full resolution as ``lights`` grows (see ``relight/render/_lights.py``)."""

    lights: int = 256

    name: ClassVar[str] = "lights"
    KEYWORDS: ClassVar[dict[str, str]] = {"lights": "lights"}

    def __check_init__(self):
        _int_at_least("lights", "lights", self.lights, 1)


class Fast(AbstractMethod):
    """Order-2 SH irradiance at the bent normal x ambient occlusion
    (Ramamoorthi & Hanrahan 2001, eq. 7-9) and split-sum specular (Karis 2013)
    with Lagarde & de Rousiers 2014's specular occlusion. ``levels``
    prefiltered roughness levels of ``prefilter_rows`` rows,
    ``prefilter_samples`` GGX samples per texel, ``ao_rays`` visibility rays per
    sample, a ``lut_size`` x ``lut_size`` DFG table."""

    levels: int = fast.DEFAULT_LEVELS
    prefilter_rows: int = fast.DEFAULT_PREFILTER_ROWS
    prefilter_samples: int = fast.DEFAULT_PREFILTER_SAMPLES
    ao_rays: int = 64
    lut_size: int = fast.DEFAULT_LUT_SIZE

    name: ClassVar[str] = "fast"
    KEYWORDS: ClassVar[dict[str, str]] = {k: k for k in
                                          ("levels", "prefilter_rows", "prefilter_samples", "ao_rays", "lut_size")}

    def __check_init__(self):
        for f, lo in (("levels", 2), ("prefilter_rows", 8), ("prefilter_samples", 1), ("ao_rays", 1), ("lut_size", 2)):
            _int_at_least("fast", f, getattr(self, f), lo)


class Reference(AbstractMethod):
    """Monte Carlo with multiple importance sampling of the environment and the
    BRDF (Veach & Guibas 1995; ``heuristic`` "power" with beta = 2, eq. 12, or
    "balance", eq. 9): ``samples`` directions per sample (passes of 64),
    ``env_fraction`` of them from environment sampling."""

    samples: int = 256
    env_fraction: float | int = 0.5
    heuristic: str = "power"

    name: ClassVar[str] = "reference"
    KEYWORDS: ClassVar[dict[str, str]] = {"samples": "samples", "env_fraction": "env_fraction",
                                          "heuristic": "heuristic"}

    def __check_init__(self):
        _int_at_least("reference", "samples", self.samples, 2)
        f = self.env_fraction
        if not (isinstance(f, (int, float)) and not isinstance(f, bool) and 0.0 <= f <= 1.0):
            raise ValueError(f"method 'reference': env_fraction must be in [0, 1], got {f!r}")
        if self.heuristic not in ("balance", "power"):
            raise ValueError(f"method 'reference': heuristic must be 'balance' or 'power', got {self.heuristic!r}")


_BY_NAME: dict[str, type[AbstractMethod]] = {cls.name: cls for cls in (Rig, Dense, Fast, Reference, Lights)}
METHODS = tuple(_BY_NAME)


def resolve_method(method, settings: dict) -> tuple[AbstractMethod, dict]:
    """(method object, the remaining settings) from ``method=`` (a string name
    or a method object) and the call's keyword settings. With a string, the
    method's own keywords build its object; with an object, giving them again
    is an error (one place for each setting)."""
    if isinstance(method, AbstractMethod):
        cls = type(method)
        given = sorted(set(settings) & set(cls.KEYWORDS))
        if given:
            raise ValueError(f"method {method.name!r} was given as an object: set {given} on it "
                             f"({cls.__name__}(...)), not as keyword settings")
        return method, dict(settings)
    if not isinstance(method, str) or method not in _BY_NAME:
        raise ValueError(f"unknown relighting method {method!r}; expected one of {METHODS} or a method object "
                         "(relight.render.Rig, Dense, Lights, Fast, Reference)")
    cls = _BY_NAME[method]
    own = {cls.KEYWORDS[k]: settings[k] for k in settings if k in cls.KEYWORDS}
    rest = {k: v for k, v in settings.items() if k not in cls.KEYWORDS}
    return cls(**own), rest
