"""The render method family's abstract base: a method is a small final equinox Module holding its
settings as fields, and it prepares and shades itself.

A method's life, as :func:`relight.render.render_samples` and :func:`relight.render.render_view`
run it:

1. ``lighting = method.prepare(env, dtype=...)``: what it precomputes from the environment alone
   (its own typed pytree: light directions and strengths, SH coefficients, sampling tables), reused
   for any geometry, view or camera orbit.
2. ``geometry = method.geometry(lighting, maps, surface, mesh, visibility, terminator=...)``: what it
   needs from the mesh (visibility rows, ambient occlusion, a ray caster), computed once and reused
   across environment rotations.
3. ``radiance, M = method.shade(lighting, geometry, maps, surface, wo, rotation=..., key=...)``: the
   radiance toward ``wo`` by the method's chunk shader (:meth:`AbstractMethod.chunk_shader`) over
   fixed-shape chunks, plus the subsurface term (``relight.render._shading.shade_chunks``).
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import skin_bssrdf

from ._shading import shade_chunks

__all__ = ["AbstractMethod"]


def int_at_least(owner: str, name: str, value, lo: int, alias: str | None = None) -> None:
    """ValueError naming method ``owner``'s setting ``name`` unless ``value`` is an integer >= ``lo``."""
    if not isinstance(value, (int, np.integer)) or isinstance(value, bool) or value < lo:
        label = f"{name!r}" if alias is None else f"{name!r} (keyword {alias!r})"
        raise ValueError(f"method {owner!r}: setting {label} must be an integer >= {lo}, got {value!r}")


class AbstractMethod(eqx.Module):
    """A render method and its settings, which prepares and shades itself.

    Class attributes:
        name: the method's string spelling (the CLI's ``--method``).
        KEYWORDS: the keyword settings of the string spelling, mapped to field names.
    """

    name: ClassVar[str]
    KEYWORDS: ClassVar[dict[str, str]]

    def settings(self) -> dict:
        """The settings under their keyword names (``resolution`` for Dense's rows)."""
        inv = {field: kw for kw, field in self.KEYWORDS.items()}
        return {inv[f]: getattr(self, f) for f in inv}

    @abc.abstractmethod
    def prepare(self, env, *, dtype=jnp.float32) -> Any:
        """What the method precomputes from the environment alone.

        Args:
            env: ``relight.envmap.EnvMap``.
            dtype: float dtype of the computation.

        Returns:
            The method's prepared-lighting pytree.
        """

    @abc.abstractmethod
    def geometry(self, lighting, maps, surface, mesh=None, visibility=None, *, terminator: bool = True) -> Any:
        """What the method needs from the mesh, computed once (not differentiated).

        Args:
            lighting: this method's :meth:`prepare` output.
            maps: ``relight.MaterialMaps`` over the surface's samples.
            surface: ``stage.Surface``.
            mesh: ``stage.Mesh`` casting shadows (None: no shadowing).
            visibility: a precomputed bool [P, D] or ``stage.PackedMask`` (directional methods only).
            terminator: shadow rays from the smooth surface (``stage.Occluder``).

        Returns:
            The method's geometry pytree.
        """

    @abc.abstractmethod
    def default_chunk(self) -> int:
        """Samples per chunk when the call gives no ``chunk``."""

    @abc.abstractmethod
    def chunk_shader(self, lighting, geometry, *, rotation=None, key=None, eta: float = skin_bssrdf.SKIN_ETA):
        """The per-chunk integral of the reflection equation.

        Args:
            lighting: this method's :meth:`prepare` output.
            geometry: this method's :meth:`geometry` output.
            rotation: optional 3x3 rotation of the environment.
            key: ``jax.random`` key (methods that sample).
            eta: relative index of the subsurface Fresnel transmittances.

        Returns:
            ``shader(chunk, want_sss)`` -> (radiance [c, C], subsurface irradiance [c, C]) of a
            ``relight.render._shading.Chunk``.
        """

    def shade(self, lighting, geometry, maps, surface, wo, *, rotation=None, key=None,
              eta: float = skin_bssrdf.SKIN_ETA, chunk: int | None = None, operator=None, sss_exitance=None):
        """Radiance toward ``wo`` and the subsurface term's radiant exitance.

        Args:
            lighting: this method's :meth:`prepare` output.
            geometry: this method's :meth:`geometry` output for ``surface``.
            maps: ``relight.MaterialMaps`` over the surface's P samples.
            surface: ``stage.Surface``.
            wo: [P, 3] unit directions toward the viewer (world).
            rotation: optional 3x3 rotation of the environment (light from d arrives from R d).
            key: ``jax.random`` key of the sampling methods.
            eta: relative index of the subsurface Fresnel transmittances.
            chunk: samples per step (None: :meth:`default_chunk`).
            operator: a prebuilt ``skin_bssrdf.DiffusionOperator`` on the samples.
            sss_exitance: optional precomputed radiant exitance M [P, C].

        Returns:
            (radiance [P, C], never NaN or Inf; M [P, C], None when no sample is SUBSURFACE).

        References:
            Kajiya 1986 (the rendering equation, direct term); Jensen et al. 2001, eq. 5.
        """
        shader = self.chunk_shader(lighting, geometry, rotation=rotation, key=key, eta=eta)
        return shade_chunks(shader, self.default_chunk(), lighting.dtype, maps, surface, wo, eta=eta, chunk=chunk,
                            operator=operator, sss_exitance=sss_exitance)
