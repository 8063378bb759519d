"""Image-based relighting from a one-light-at-a-time (OLAT) stack
(Debevec et al. 2000, "Acquiring the Reflectance Field of a Human Face",
SIGGRAPH; the reflectance-field sum in discrete form):

    relit[..., p, c] = sum_l  weights[l, c] * radiance[..., l, p, c]

with weights from :func:`relight.envmap.light_weights` (or its barycentric
variant). Works for texel-space (P = texels) and image-space (P = H * W pixels)
stacks alike; float16 storage is read and accumulated in float32.

Why this loop and not ``jnp.einsum``: the product is memory-bound (one
multiply-add per byte pair read), and XLA lowers the light-axis reduction of a
light-major ``[L, P, C]`` array to a column reduction that touches L separate
streams per output vector, or, with the per-channel weight broadcast fused in,
to scalar code for the ``index mod C`` arithmetic; both ran at ~0.1 of the
machine's read bandwidth. Here the samples are cut into chunks of a few
thousand contiguous values (the float32 accumulator stays in L1); for each
chunk the lights are streamed in order, each adding one contiguous row
segment, viewed as [rows, period], times that light's weights repeated over
one period (a multiple of C and of the vector width, so the broadcast runs
along the major axis and the fused loop body is a plain vectorised
multiply-add). That reads the stack exactly once, sequentially per light,
and runs at about numpy's read bandwidth for float32 and float16 alike
(scripts/bench_relight.py, docs/relight_io.md). An earlier version
multiplied by a weight row pre-broadcast over the whole chunk ([L, chunk]
floats, out of L1/L2): that second stream held float16 to ~0.65 of it.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

__all__ = ["relight_olat", "relight_olat_sweep"]

# Floats per chunk of the flattened (sample, channel) axis (summed over the K
# outputs of a sweep). Measured on the 2-core AMD EPYC dev machines (ratio to
# numpy's bandwidth, median of interleaved rounds, 346 lights x 1e6 x RGB):
# 3072 floats ran at 0.98-1.1 (float16) and 1.1 (float32), 6144 at 1.1-1.2 and
# 1.1; 12k and above fell to 0.3-0.6 (the accumulator leaves L1).
_CHUNK_FLOATS = 6144
# Lights per loop iteration (unrolling amortises XLA's per-iteration cost):
# 1-2 reached ~0.6, 4 ~0.9, and 16 or more fell to ~0.3 (code-size effects).
_UNROLL = 4


def _check(radiance, weights):
    radiance = jnp.asarray(radiance)
    weights = jnp.asarray(weights)
    if radiance.ndim < 3:
        raise ValueError(f"OLAT radiance must be [..., L, P, C], got shape {radiance.shape}")
    if not jnp.issubdtype(radiance.dtype, jnp.floating):
        raise TypeError(f"OLAT radiance must be float32 or float16, got {radiance.dtype}")
    return radiance, weights


def _period(channels: int) -> int:
    """Length of the weight pattern along the flattened (sample, channel) axis:
    a multiple of C and of 8 float32 lanes, at least 24."""
    per = channels * 8 // math.gcd(channels, 8)
    return per * -(-24 // per)


def _relight_flat(stack: Array, w: Array, channels: int, chunk_samples: int) -> Array:
    """``stack [L, N]`` (N = P * C, channel-minor), ``w [K, L, C]`` float32 -> ``[K, N]``."""
    n_lights, n = stack.shape
    k_out = w.shape[0]
    per = _period(channels)
    width = max(per, (channels * chunk_samples) // per * per)
    n_main = (n // width) * width
    out_parts = []
    if n_main:
        # Each light's weights repeated over one period [K, L, per]; a chunk is
        # viewed as [width / per, per] so the weight row broadcasts along the
        # major axis: a plain vectorised multiply-add per light, with the
        # pattern (L x per floats) resident in cache.
        pattern = jnp.tile(w, (1, 1, per // channels))

        def chunk_body(k, out):
            def light_body(l, acc):
                seg = jax.lax.dynamic_slice(stack, (l, k * width), (1, width)).astype(jnp.float32)
                wl = jax.lax.dynamic_index_in_dim(pattern, l, axis=1, keepdims=False)  # [K, per]
                return acc + seg.reshape(1, width // per, per) * wl[:, None, :]

            acc = jax.lax.fori_loop(
                0, n_lights, light_body, jnp.zeros((k_out, width // per, per), jnp.float32), unroll=_UNROLL
            )
            return jax.lax.dynamic_update_slice(out, acc.reshape(k_out, width), (0, k * width))

        main = jax.lax.fori_loop(0, n_main // width, chunk_body, jnp.zeros((k_out, n_main), jnp.float32))
        out_parts.append(main)
    if n_main < n:  # the tail (fewer than one chunk of samples): small, plain einsum
        tail = stack[:, n_main:].astype(jnp.float32).reshape(n_lights, -1, channels)
        out_parts.append(jnp.einsum("lpc,klc->kpc", tail, w).reshape(k_out, -1))
    return out_parts[0] if len(out_parts) == 1 else jnp.concatenate(out_parts, axis=1)


@functools.partial(jax.jit, static_argnums=2)
def _relight(radiance: Array, weights: Array, chunk_samples: int | None) -> Array:
    """radiance [B..., L, P, C], weights [K, L, C] -> [K, B..., P, C] float32.

    Jitted here so that eager calls reuse one compiled loop per shape."""
    *batch, n_lights, n_samples, channels = radiance.shape
    k_out = weights.shape[0]
    if weights.shape[1:] != (n_lights, channels):
        raise ValueError(
            f"light weights of shape {weights.shape[1:]} do not match the OLAT stack's "
            f"{n_lights} lights and {channels} channels (radiance shape {radiance.shape})"
        )
    if chunk_samples is None:
        chunk_samples = max(1, _CHUNK_FLOATS // (channels * k_out))
    w = weights.astype(jnp.float32)
    flat = radiance.reshape(-1, n_lights, n_samples * channels)  # free: trailing axes are contiguous
    if flat.shape[0] == 1:
        out = _relight_flat(flat[0], w, channels, chunk_samples)[:, None]
    else:
        out = jax.lax.map(lambda s: _relight_flat(s, w, channels, chunk_samples), flat)  # [B, K, N]
        out = jnp.moveaxis(out, 1, 0)
    return out.reshape(k_out, *batch, n_samples, channels)


def relight_olat(
    radiance: Float[ArrayLike, "*batch light sample channel"],
    weights: Float[ArrayLike, "light channel"],
    chunk_samples: int | None = None,
) -> Float[Array, "*batch sample channel"]:
    """Relight an OLAT stack: ``sum_l weights[l, c] * radiance[..., l, p, c]``, float32.

    Args:
        radiance: OLAT radiance ``[..., L, P, C]`` (leading axes, e.g. views,
            are kept), float32 or float16 (accumulated in float32).
        weights: per-light, per-channel weights ``[L, C]`` (dimensionless; from
            :func:`relight.envmap.light_weights`, convention
            ``relit = sum_l w_l OLAT_l``).
        chunk_samples: samples per chunk (static); default ~6k floats of data.

    Returns:
        Relit radiance ``[..., P, C]`` float32, in the stack's units.

    Works under ``jax.jit`` and ``jax.vmap``, and is differentiable in both
    arguments. Peak extra memory: the output plus ``L x chunk`` floats.
    """
    radiance, weights = _check(radiance, weights)
    if weights.ndim != 2:
        raise ValueError(f"light weights must be [L, C], got shape {weights.shape}")
    return _relight(radiance, weights[None], chunk_samples)[0]


def relight_olat_sweep(
    radiance: Float[ArrayLike, "*batch light sample channel"],
    weights: Float[ArrayLike, "sweep light channel"],
    chunk_samples: int | None = None,
) -> Float[Array, "sweep *batch sample channel"]:
    """Relight one OLAT stack under K lightings at once (e.g. a turntable of K
    environment rotations from :func:`relight.envmap.rotation_sweep_weights`),
    reading the stack once: ``out[k] = relight_olat(radiance, weights[k])``.

    Cost: one pass over the stack plus K multiply-adds per value (K = 4 took
    1.9-2.5x one relight, against 4x for four passes; scripts/bench_relight.py
    --sweep 4); peak extra memory is the K outputs.
    """
    radiance, weights = _check(radiance, weights)
    if weights.ndim != 3:
        raise ValueError(f"sweep weights must be [K, L, C], got shape {weights.shape}")
    return _relight(radiance, weights, chunk_samples)
