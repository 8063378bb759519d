"""Model-based relighting of surface samples: outgoing radiance toward a view direction from
material maps under an environment map, by a render method (``relight.render``'s method Modules:
``Rig``, ``Dense``, ``Lights``, ``Fast``, ``Reference``; each prepares and shades itself, see
``relight/render/_abstract.py``), and the method registry of the string spellings.

The reflection equation every method computes is in ``relight/render/_shading.py``. Radiance is in
the environment map's units (radiance per sr).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import skin_bssrdf
import stage

from ..envmap._latlong import EnvMap
from ..materials._maps import MaterialMaps
from ._abstract import AbstractMethod, int_at_least
from ._dense import Dense
from ._fast import Fast
from ._lights import Lights
from ._reference import Reference
from ._rig import Rig
from ._shading import check_inputs

__all__ = ["DEFAULTS", "METHODS", "method_from_name", "render_samples", "resolve_method"]

# The string spellings (the CLI's --method) of the method Modules.
_BY_NAME: dict[str, type[AbstractMethod]] = {cls.name: cls for cls in (Rig, Dense, Fast, Reference, Lights)}
METHODS = tuple(_BY_NAME)
# Settings of each method and their defaults (their one home is the method Modules' fields).
DEFAULTS: dict[str, dict[str, Any]] = {name: cls().settings() for name, cls in _BY_NAME.items()}
# The settings every method shares: keyword arguments of render_samples / render_view / turntable.
_COMMON = {"chunk": None, "eta": skin_bssrdf.SKIN_ETA, "operator": None, "rotation": None, "dtype": jnp.float32,
           "terminator": True}


def method_from_name(name: str, **settings) -> AbstractMethod:
    """The method Module of a string spelling, built with its keyword settings.

    Args:
        name: one of ``METHODS`` ("rig", "dense", "fast", "reference", "lights").
        **settings: the method's keyword settings (``Dense``: ``resolution``; the others: their
            field names), checked when the Module is built.

    Returns:
        ``Rig``, ``Dense``, ``Fast``, ``Reference`` or ``Lights`` holding the settings.
    """
    method, rest = resolve_method(name, settings)
    if rest:
        raise ValueError(f"method {name!r} has no setting(s) {sorted(rest)}; its settings are "
                         f"{sorted(type(method).KEYWORDS)}")
    return method


def resolve_method(method, settings: dict) -> tuple[AbstractMethod, dict]:
    """(method Module, the remaining settings) from ``method=`` and a call's keyword settings.

    Args:
        method: a method Module, or a string name whose keyword settings build its Module.
        settings: the call's keyword settings.

    Returns:
        The Module and the settings it did not take. Giving a Module's own settings again as keywords
        is an error (one place for each setting).
    """
    if isinstance(method, AbstractMethod):
        cls = type(method)
        given = sorted(set(settings) & set(cls.KEYWORDS))
        if given:
            raise ValueError(f"method {method.name!r} was given as an object: set {given} on it "
                             f"({cls.__name__}(...)), not as keyword settings")
        return method, dict(settings)
    cls = _BY_NAME.get(method) if isinstance(method, str) else None
    if cls is None:
        raise ValueError(f"unknown relighting method {method!r}; expected one of {METHODS} or a method object "
                         "(relight.render.Rig, Dense, Lights, Fast, Reference)")
    own = {cls.KEYWORDS[k]: settings[k] for k in settings if k in cls.KEYWORDS}
    rest = {k: v for k, v in settings.items() if k not in cls.KEYWORDS}
    return cls(**own), rest


def _settings(method, settings: dict) -> dict:
    """The resolved settings: the method Module (``settings["method"]``, from a string name and its
    keywords or given as a Module, validated when built) and its settings flattened under their
    keyword names, plus the settings every method shares (checked here)."""
    m, rest = resolve_method(method, settings)
    unknown = sorted(set(rest) - set(_COMMON))
    if unknown:
        raise ValueError(f"method {m.name!r} has no setting(s) {unknown}; its settings are "
                         f"{sorted(set(_COMMON) | set(type(m).KEYWORDS))}")
    out = {**_COMMON, **rest, **m.settings(), "method": m}
    if out["chunk"] is not None:
        int_at_least(m.name, "chunk", out["chunk"], 1)
        out["chunk"] = int(out["chunk"])
    if not (isinstance(out["eta"], (int, float)) and out["eta"] >= 1.0):
        raise ValueError(f"setting 'eta' (relative index of refraction) must be a float >= 1, got {out['eta']!r}")
    if not isinstance(out["terminator"], bool):
        raise ValueError(f"setting 'terminator' must be True or False, got {out['terminator']!r}")
    if out["rotation"] is not None:
        r = np.asarray(out["rotation"], np.float64)
        if r.shape != (3, 3) or not np.all(np.isfinite(r)) or not np.allclose(r @ r.T, np.eye(3), atol=1e-4):
            raise ValueError(f"setting 'rotation' must be a 3x3 rotation matrix, got {r.shape} / not orthonormal")
    return out


def _with_rig(method, rig, settings: dict) -> None:
    """``render_samples``' ``rig=`` put into the settings of the string spelling of ``Rig``."""
    if rig is None:
        return
    if isinstance(method, AbstractMethod):
        raise ValueError("rig= with a method object: give it as relight.render.Rig(rig=...)")
    if _BY_NAME.get(method) is not Rig:
        raise ValueError(f"rig= is a setting of method 'rig', not of {method!r}")
    settings["rig"] = rig


def render_samples(maps: MaterialMaps, surface: stage.Surface, env: EnvMap, wo_world, *,
                   method: str | AbstractMethod = "rig",
                   mesh: stage.Mesh | None = None, rig: stage.Rig | None = None, visibility=None, key=None,
                   **settings) -> Float[Array, "sample 3"]:
    """Relit outgoing radiance at each surface sample toward the viewer.

    The direct reflection of the environment off the material maps, with shadows from ray casting
    against ``mesh``, plus for samples with model == SUBSURFACE the diffusion term spread by a
    ``skin_bssrdf.DiffusionOperator`` (equations in ``relight/render/_shading.py``). The method
    prepares the lighting (``method.prepare``), its geometry (``method.geometry``) and shades
    (``method.shade``).

    Args:
        maps: ``relight.MaterialMaps`` over the surface's P samples (shading frame from the maps,
            ``MaterialMaps.frame``).
        surface: ``stage.Surface`` (positions in mm; its interpolated normals give the horizon
            test; shadow rays leave along the mesh's face normals, see ``stage.Occluder``).
        env: ``relight.envmap.EnvMap`` (lat-long, radiance in its own units; the result is in the
            same units).
        wo_world: [P, 3] or [3] unit directions toward the viewer (world).
        method: a method Module (``Rig``, ``Dense``, ``Fast``, ``Reference``, ``Lights``, holding its
            settings), or a string of ``METHODS`` whose settings are then keyword arguments (the
            fields of its Module; ``Dense``'s ``rows`` as ``resolution``), built by
            :func:`method_from_name`.
        mesh: ``stage.Mesh`` casting shadows (None: every direction above the shading horizon is
            lit); visibility is computed once here (pass ``visibility`` to reuse it).
        rig: the rig of the string spelling "rig" (default ``stage.light_stage_x()``).
        visibility: precomputed bool [P, D] or ``stage.PackedMask`` of a directional method: "rig"
            (D = lights, ``stage.light_visibility``), "dense" (D = 2 resolution^2 lat-long pixel
            directions, row-major) or "lights" (D = lights, in ``median_cut``'s order).
        key: ``jax.random`` key of ``Reference`` (default PRNGKey(0)).
        **settings: shared by every method: ``chunk`` samples per step (bounded memory; default
            4096 for the directional methods, 16384 for fast, 2^18 / samples for reference);
            ``eta`` (``skin_bssrdf.SKIN_ETA``) the relative index of the subsurface Fresnel
            transmittances; ``operator`` a prebuilt ``DiffusionOperator`` on the same samples
            (default :func:`build_operator`); ``rotation`` a 3x3 rotation of the environment (light
            that arrived from d arrives from R d; exact for every method except "dense" at rotations
            other than whole pixels about y); ``dtype`` (float32); ``terminator`` (True) shadow rays
            from the smooth surface the interpolated normals describe (Hanika 2021, see
            ``stage.Occluder``), False from the flat facets (as Mitsuba 3 and pbrt-v4 cast them).

    Returns:
        Radiance [P, 3] (float32 by default), never NaN or Inf. ValueError on an unknown method or
        setting, inputs of the wrong type or shape, or maps and surface of different sizes.

    References:
        Kajiya 1986, "The Rendering Equation" (direct term); Jensen et al. 2001, "A Practical Model
        for Subsurface Light Transport", eq. 5; each method's own in its Module.
    """
    _with_rig(method, rig, settings)
    s = _settings(method, settings)
    m = s["method"]
    wo = check_inputs(maps, surface, env, wo_world)
    if mesh is not None and not isinstance(mesh, stage.Mesh):
        raise ValueError(f"mesh must be a stage.Mesh or None, got {type(mesh).__name__}")
    lighting = m.prepare(env, dtype=s["dtype"])
    geometry = m.geometry(lighting, maps, surface, mesh, visibility, terminator=s["terminator"])
    out, _ = m.shade(lighting, geometry, maps, surface, wo, rotation=s["rotation"], key=key, eta=s["eta"],
                     chunk=s["chunk"], operator=s["operator"])
    return out
