"""What every render method shares: input checks, the subsurface operator, fixed-shape sample
chunks and the chunked shading loop that adds the subsurface term.

Every method computes the direct-lighting reflection equation with the environment as the only
light (pbrt-v4 eq. 4.14 / Kajiya 1986 without interreflection):

    L_o(x, wo) = int_S2 f_r(x, wi, wo) max(0, n.wi) L_env(R^T wi) V(x, wi) dwi
                 + [model = SUBSURFACE] F_t(eta, n.wo) / pi * M(x)

    M(x) = sum_j w_xj E_j,  E_j = int F_t(eta, n.wi) max(0, n.wi) L_env(R^T wi) V(x_j, wi) dwi

(f_r the sample's :class:`relight.LadderBRDF`; V the ray-cast visibility, including the geometric
horizon; the subsurface term is Jensen et al. 2001's diffusion BSSRDF, eq. 5, through
``skin_bssrdf.DiffusionOperator``, exactly as ``stage.simulate`` applies it; R an optional rotation
of the environment). A method supplies the per-chunk integral (its ``chunk_shader``); the loop
here chunks the samples and adds the subsurface term.
"""

from __future__ import annotations

from collections.abc import Callable

import jax.numpy as jnp
import numpy as np

import skin_bssrdf
import stage
from brdf import safe_normalize

from ..envmap._latlong import EnvMap
from ..materials._maps import SUBSURFACE, LadderBRDF, MaterialMaps

__all__ = ["Chunk", "build_operator", "check_inputs", "env_rotation", "material", "shade_chunks"]


def check_inputs(maps, surface, env, wo_world=None):
    """The shared inputs checked (ValueError naming the problem).

    Args:
        maps: ``relight.MaterialMaps`` over P samples.
        surface: ``stage.Surface`` of the same P samples.
        env: ``relight.envmap.EnvMap`` with as many channels as ``maps.rho_d``.
        wo_world: optional [P, 3] or [3] view directions.

    Returns:
        ``wo_world`` broadcast to [P, 3] (None without it).
    """
    if not isinstance(maps, MaterialMaps):
        raise ValueError(f"maps must be a relight.MaterialMaps, got {type(maps).__name__}")
    if not isinstance(surface, stage.Surface):
        raise ValueError(f"surface must be a stage.Surface, got {type(surface).__name__}")
    if not isinstance(env, EnvMap):
        raise ValueError(f"env must be a relight.envmap.EnvMap (lat-long), got {type(env).__name__}")
    if env.radiance.shape[-1] != maps.rho_d.shape[-1]:
        raise ValueError(f"env has {env.radiance.shape[-1]} channels but the maps' rho_d has {maps.rho_d.shape[-1]}")
    P = surface.num_samples
    if maps.num_samples != P:
        raise ValueError(f"maps have {maps.num_samples} samples but the surface has {P}: "
                         "they must describe the same samples")
    shapes = {"rho_d": (P, 3), "rho_s": (P, 1), "alpha": (P, 2), "normal": (P, 3), "tangent": (P, 3), "mfp": (P, 3),
              "model": (P,)}
    for name, shp in shapes.items():
        got = tuple(getattr(maps, name).shape)
        if got != shp:
            raise ValueError(f"maps.{name} must have shape {list(shp)}, got {list(got)}")
    if wo_world is None:
        return None
    wo = jnp.asarray(wo_world)
    if wo.shape == (3,):
        wo = jnp.broadcast_to(wo, (P, 3))
    if wo.shape != (P, 3):
        raise ValueError(f"wo_world must be [P, 3] = [{P}, 3] or [3], got {list(wo.shape)}")
    return wo


def concrete(x):
    """``x`` as a NumPy array, or None when it is traced (under jit / grad)."""
    try:
        return np.asarray(x)
    except Exception:  # a tracer (under jit/grad): treat the value as unknown
        return None


def build_operator(maps: MaterialMaps, surface: stage.Surface) -> skin_bssrdf.DiffusionOperator:
    """The diffusion operator on the surface's samples for the maps' subsurface samples.

    Args:
        maps: material maps (concrete model map) over the surface's samples.
        surface: the samples the operator couples (positions in mm, areas in mm^2).

    Returns:
        A ``skin_bssrdf.DiffusionOperator`` whose radius is ``skin_bssrdf.operator_radius`` of the
        maps' profiles over the SUBSURFACE samples.

    References:
        Jensen et al. 2001, "A Practical Model for Subsurface Light Transport", eq. 5.
    """
    radius = skin_bssrdf.operator_radius(maps.profile(), where=np.asarray(maps.model) == SUBSURFACE)
    return skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius)


def env_rotation(rotation, dtype):
    """The 3x3 environment rotation as an array of ``dtype`` (the identity for None)."""
    return jnp.eye(3, dtype=dtype) if rotation is None else jnp.asarray(rotation, dtype)


def material(m, extra_axis: bool = False) -> LadderBRDF:
    """The ``LadderBRDF`` of a chunk's material tuple (rho_d, rho_s, alpha, model, ...), with an
    axis for directions inserted after the samples' when ``extra_axis``."""
    rho_d, rho_s, alpha, model = m[0], m[1], m[2], m[3]
    if extra_axis:
        rho_d, rho_s, alpha = rho_d[:, None, :], rho_s[:, None, :], alpha[:, None, :]
        return LadderBRDF(rho_d, rho_s, alpha, model[:, None, None])
    return LadderBRDF(rho_d, rho_s, alpha, model[:, None])


class _Chunks:
    """Fixed-shape chunks of per-sample arrays: one gather pads an array to whole chunks (repeating
    the last sample), each chunk is then a static slice (a gather per array and chunk cost ~0.1 s per
    view in dispatch overhead). The arrays in ``cached`` are padded once."""

    def __init__(self, pad_idx, chunk, n_chunks, padded, cached):
        self.pad_idx, self.chunk, self.n_chunks, self.padded = pad_idx, chunk, n_chunks, padded
        self.cached = [(a, self.padder(a)) for a in cached]

    def padder(self, a):
        return a[self.pad_idx] if self.padded else a

    def take(self, s0, a):
        p = next((padded for orig, padded in self.cached if orig is a), None)
        p = self.padder(a) if p is None else p
        return p[s0:s0 + self.chunk] if self.n_chunks > 1 else p


class Chunk:
    """One fixed-shape chunk of samples, as a method's chunk shader sees it.

    Attributes:
        number: the chunk's position in the loop (0, 1, ...).
        index: int [chunk] the samples' indices (the last one repeated in a padded chunk).
        m: the material tuple (rho_d, rho_s, alpha, model, tangent, bitangent, normal) of the chunk.
    """

    def __init__(self, chunks: _Chunks, s0: int, number: int, index: np.ndarray, m: tuple, pos, wo, ng):
        self._chunks, self._s0 = chunks, s0
        self.number, self.index, self.m = number, index, m
        self._pos, self._wo, self._ng = pos, wo, ng

    def take(self, a):
        """The chunk's rows of a per-sample array ``a`` [P, ...]."""
        return self._chunks.take(self._s0, a)

    @property
    def position(self):
        return self.take(self._pos)

    @property
    def wo(self):
        return self.take(self._wo)

    @property
    def geometric_normal(self):
        return self.take(self._ng)


def shade_chunks(shader: Callable[[Chunk], tuple], default_chunk: int, dtype, maps: MaterialMaps,
                 surface: stage.Surface, wo, *, eta: float, chunk: int | None = None, operator=None,
                 sss_exitance=None):
    """Radiance toward ``wo`` by a method's chunk shader over fixed-shape sample chunks, plus the
    subsurface term.

    Args:
        shader: ``shader(chunk, want_sss)`` -> (radiance [c, C], subsurface irradiance [c, C]).
        default_chunk: samples per chunk when ``chunk`` is None.
        dtype: the computation's float dtype.
        maps: material maps over the surface's P samples.
        surface: the samples.
        wo: [P, 3] directions toward the viewer (world).
        eta: relative index of the subsurface Fresnel transmittances.
        chunk: samples per chunk (None: ``default_chunk``).
        operator: a ``DiffusionOperator`` on the samples (None: :func:`build_operator`).
        sss_exitance: optional precomputed radiant exitance M [P, C] of the subsurface term.

    Returns:
        (radiance [P, C], never NaN or Inf; M [P, C], None when no sample is SUBSURFACE).

    References:
        Jensen et al. 2001, eq. 5 (the subsurface term; see the module docstring).
    """
    dt = dtype
    P = surface.num_samples
    fr = maps.frame(surface)
    m_all = (jnp.asarray(maps.rho_d, dt), jnp.asarray(maps.rho_s, dt), jnp.asarray(maps.alpha, dt),
             jnp.asarray(maps.model, jnp.int32), jnp.asarray(fr.tangent, dt), jnp.asarray(fr.bitangent, dt),
             jnp.asarray(fr.normal, dt))
    pos = jnp.asarray(surface.position, dt)
    ng = jnp.asarray(surface.normal, dt)
    wo = safe_normalize(jnp.asarray(wo, dt))
    model_np = concrete(maps.model)
    if model_np is None and operator is None and sss_exitance is None:
        raise ValueError("maps.model is traced (under jit/grad): pass it as a concrete array, or pass operator= "
                         "so the subsurface term can be evaluated")
    has_sss = model_np is None or bool(np.any(model_np == SUBSURFACE))
    want_sss = has_sss and sss_exitance is None
    # Chunks have a fixed shape (the last one padded by repeating the final sample); P is rounded up
    # to a power of two (>= 64) first, so that views with different hit counts (orbit frames) share
    # one compilation.
    chunk = min(chunk or default_chunk, max(64, 1 << (P - 1).bit_length()))
    n_chunks = -(-P // chunk)
    outs, es = [], []
    pad_idx = np.minimum(np.arange(n_chunks * chunk), P - 1)
    chunks = _Chunks(pad_idx, chunk, n_chunks, n_chunks * chunk != P, (pos, wo, ng))
    m_pad = tuple(chunks.padder(a) for a in m_all)
    for c in range(n_chunks):
        s0 = c * chunk
        n = min(chunk, P - s0)
        m = tuple(a[s0:s0 + chunk] for a in m_pad) if n_chunks > 1 else m_pad
        out, e = shader(Chunk(chunks, s0, c, pad_idx[s0:s0 + chunk], m, pos, wo, ng), want_sss)
        outs.append(out[:n])
        es.append(e[:n])
    out = jnp.concatenate(outs) if len(outs) > 1 else outs[0]
    e_sss = jnp.concatenate(es) if len(es) > 1 else es[0]
    M = None
    if has_sss:
        is_sss = (m_all[3] == SUBSURFACE)[:, None]
        if sss_exitance is None:
            e_in = jnp.where(is_sss, e_sss, 0.0)
            op = operator if operator is not None else build_operator(maps, surface)
            M = op.apply(maps.profile(), e_in.astype(op.distance.dtype)).astype(dt)
        else:
            M = jnp.asarray(sss_exitance, dt)
        wo_l = stage.to_local(wo, m_all[4], m_all[5], m_all[6])
        seen = is_sss[:, 0] & (wo_l[:, 2] > 0)
        out = out + stage.subsurface_exitance(M, wo_l, float(eta), seen)
    return jnp.where(jnp.isfinite(out), out, 0.0), M
