"""The directional methods' shared part (``Rig``, ``Dense``, ``Lights``): a set of D lights (near-field
positions or distant directions) with strengths, per-sample visibility rows [P, D] cast once from the
mesh, and the kernel summing f_r cos E V over the lights through stage's OLAT forward model.
"""

from __future__ import annotations

import abc
import functools
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import skin_bssrdf
import stage

from ._abstract import AbstractMethod
from ._shading import material

__all__ = ["AbstractDirectional", "DirectionalGeometry", "direction_visibility", "visibility_rows"]

# Directions (lights or environment pixels) per step of the scan inside the directional kernel: the
# working set is chunk x _DIR_BLOCK x C floats (~10 temporaries of 4096 x 64 x 3 float32 ~ 30 MB).
_DIR_BLOCK = 64
# Directions per kernel call (padded): one compilation serves every rig and dense resolution; larger
# sets loop over calls. Sets smaller than that are padded to the next power of two >= _DIR_BLOCK only
# (64 or 128: at most three compilations), so a 64-light set does not pay for 256 directions.
_DIR_CALL = 256
# Default samples per chunk of the directional kernel.
_CHUNK_DIRECTIONAL = 4096
# A distant light for stage.light_visibility: a point this far along its direction (mm).
_FAR_MM = 1e3


def direction_visibility(mesh: stage.Mesh, surface: stage.Surface, directions: np.ndarray,
                         terminator: bool = True) -> np.ndarray:
    """Which distant directions each sample sees, by ray casting.

    Args:
        mesh: the occluding ``stage.Mesh``.
        surface: the samples.
        directions: [D, 3] directions (normalised here).
        terminator: as ``stage.light_visibility`` (shadow rays from the smooth surface).

    Returns:
        bool [P, D]: ``stage.light_visibility`` with a distant rig whose lights are ``directions``.
    """
    d = np.asarray(directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    with jax.ensure_compile_time_eval():  # concrete under an outer jit: the ray caster reads it on the host
        rig = stage.Rig(position=jnp.asarray(d * _FAR_MM, jnp.float32), intensity=jnp.ones((len(d), 1), jnp.float32),
                        solid_angle=jnp.full((len(d),), 4 * np.pi / len(d), jnp.float32), near_field=False)
    return np.asarray(stage.light_visibility(mesh, surface, rig, terminator=terminator))


def visibility_rows(vis, index: np.ndarray) -> np.ndarray:
    """bool [N, D]: the rows ``index`` of a visibility ``vis`` (bool [P, D] or ``stage.PackedMask``)."""
    if isinstance(vis, stage.PackedMask):
        return np.unpackbits(vis.bits[index], axis=-1, count=vis.n).astype(bool)
    return np.asarray(vis)[index]


def _dir_call(n_dirs: int) -> int:
    """Directions per kernel call for a set of ``n_dirs``."""
    return _DIR_CALL if n_dirs >= _DIR_CALL else max(_DIR_BLOCK, 1 << (n_dirs - 1).bit_length())


def _pad_directions(light, strength, n_dirs):
    pad = (-n_dirs) % _dir_call(n_dirs)
    if pad:
        light = jnp.concatenate([light, jnp.repeat(light[-1:], pad, axis=0)])
        strength = jnp.concatenate([strength, jnp.zeros((pad,) + strength.shape[1:], strength.dtype)])
    return light, strength, pad


@functools.partial(jax.jit, static_argnames=("near_field", "want_sss"))
def _directional_kernel(m, pos, wo, light, strength, vis, eta, near_field: bool, want_sss: bool):
    """sum over directions of f cos E V (and of F_t cos E V for subsurface) for one sample chunk;
    ``light`` [D, 3] positions (near field) or unit directions, ``strength`` [D, C], ``vis`` [Pc, D];
    D a multiple of _DIR_BLOCK.

    The OLAT forward model of ``stage.simulate``, term for term: ``stage.incident_light`` (inverse
    square for near-field lights), ``stage.to_local``, ``stage.reflected_radiance_lights`` (f_r cos_i
    E V) and ``stage.subsurface_irradiance`` (F_t cos_i E V, Jensen et al. 2001 eq. 5)."""
    t, b, n = m[4], m[5], m[6]
    mat = material(m)
    wo_l = stage.to_local(wo, t, b, n)
    D, C = strength.shape
    nb = D // _DIR_BLOCK
    xs = (light.reshape(nb, _DIR_BLOCK, 3), strength.reshape(nb, _DIR_BLOCK, C),
          vis.T.reshape(nb, _DIR_BLOCK, pos.shape[0]))

    def body(carry, x):
        lb, sb, vb = x
        wi, irr = stage.incident_light(lb, sb, near_field, pos)  # [B, Pc, 3], [B, Pc, C]
        wi_l = stage.to_local(wi, t, b, n)
        acc = carry[0] + jnp.sum(stage.reflected_radiance_lights(mat, wi_l, wo_l, irr, vb), axis=0)
        e = carry[1] + jnp.sum(stage.subsurface_irradiance(wi_l, irr, eta, vb), axis=0) if want_sss else carry[1]
        return (acc, e), None

    z = jnp.zeros((pos.shape[0], C), strength.dtype)
    (acc, e), _ = jax.lax.scan(body, (z, z), xs)
    return acc, e


class DirectionalGeometry(eqx.Module):
    """A directional method's geometry: visibility ``vis`` (bool [P, D] or ``stage.PackedMask``; None:
    every light visible), and the ``mesh``, ``surface`` and ``terminator`` it was cast with (to cast
    anew for lights that move with the environment)."""

    vis: Any = None
    mesh: stage.Mesh | None = None
    surface: stage.Surface | None = None
    terminator: bool = eqx.field(default=True, static=True)


class AbstractDirectional(AbstractMethod):
    """A method whose lighting is a set of D lights shaded by the directional kernel with per-sample
    visibility rows. Members say how many lights they have (:meth:`num_directions`), where they are
    and how strong under a rotation (:meth:`light_set`), and how their visibility is cast
    (:meth:`cast_visibility`)."""

    @abc.abstractmethod
    def num_directions(self, lighting) -> int:
        """The number D of lights."""

    @abc.abstractmethod
    def light_set(self, lighting, rotation) -> tuple[Any, Any, bool]:
        """(light positions or directions [D, 3], strength [D, C], near_field) under the environment
        rotated by ``rotation`` (None: unrotated)."""

    def cast_visibility(self, lighting, mesh: stage.Mesh, surface: stage.Surface, terminator: bool):
        """Visibility [P, D] of the lights from ``mesh`` (packed): distant directions ``lighting.dirs``."""
        return stage.PackedMask.pack(direction_visibility(mesh, surface, np.asarray(lighting.dirs), terminator))

    def visibility_under(self, lighting, geometry: DirectionalGeometry, light, rotation):
        """The [P, D] visibility the kernel reads for lights at ``light`` (default: the cached one)."""
        return geometry.vis

    def geometry(self, lighting, maps, surface, mesh=None, visibility=None, *, terminator: bool = True):
        P = surface.num_samples
        D = self.num_directions(lighting)
        if visibility is not None:
            shp = visibility.shape if isinstance(visibility, stage.PackedMask) else np.shape(visibility)
            if tuple(shp) != (P, D):
                raise ValueError(f"visibility must be [P, D] = [{P}, {D}] for method {self.name!r}, got {list(shp)}")
            return DirectionalGeometry(visibility, mesh, surface, terminator)
        vis = None if mesh is None else self.cast_visibility(lighting, mesh, surface, terminator)
        return DirectionalGeometry(vis, mesh, surface, terminator)

    def default_chunk(self) -> int:
        return _CHUNK_DIRECTIONAL

    def chunk_shader(self, lighting, geometry, *, rotation=None, key=None, eta: float = skin_bssrdf.SKIN_ETA):
        light, strength, near = self.light_set(lighting, rotation)
        D = light.shape[0]
        vis = self.visibility_under(lighting, geometry, light, rotation)
        light, strength, pad = _pad_directions(light, strength, D)
        call = _dir_call(D)

        def shader(chunk, want_sss):
            if vis is None:
                v = np.ones((len(chunk.index), D), bool)
            else:
                v = visibility_rows(vis, chunk.index)
            if pad:
                v = np.concatenate([v, np.zeros((len(chunk.index), pad), bool)], axis=1)
            out = e = None
            for d0 in range(0, v.shape[1], call):
                d1 = d0 + call
                o, ee = _directional_kernel(chunk.m, chunk.position, chunk.wo, light[d0:d1], strength[d0:d1],
                                            jnp.asarray(v[:, d0:d1]), float(eta), near, want_sss)
                out, e = (o, ee) if out is None else (out + o, e + ee)
            return out, e

        return shader
