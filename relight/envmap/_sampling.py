"""Importance sampling of lat-long environment maps (pbrt-v4's
PiecewiseConstant2D over the equirectangular domain, Pharr et al.,
"Physically Based Rendering", 4th ed., sec. A.5 and 12.5).

Each pixel is chosen with probability proportional to its luminance times its
solid angle; within the pixel the direction is uniform in solid angle (uniform
in azimuth and in cos theta), so the density per steradian is piecewise
constant: ``pdf(d) = P(pixel) / dOmega(pixel)``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float, Int

from brdf import safe_sqrt, widest_float

from ._latlong import EnvMap, direction_to_latlong, latlong_solid_angles

__all__ = ["EnvSampler", "envmap_pdf", "envmap_sampler", "sample_envmap"]

# Rec. 709 / sRGB luminance weights: the sampling density follows perceived
# brightness, which for RGB maps is what the integrands weight most.
_LUMA = (0.2126, 0.7152, 0.0722)


class EnvSampler(eqx.Module):
    """Sampling tables of one lat-long map.

    Attributes:
        pixel_prob: ``[H, W]`` probability of each pixel (sums to 1).
        marginal_cdf: ``[H + 1]`` CDF over rows.
        conditional_cdf: ``[H, W + 1]`` CDF over columns within each row.
        radiance: ``[H, W, C]`` the map (returned with each sample).
    """

    pixel_prob: Float[Array, "H W"]
    marginal_cdf: Float[Array, " H1"]
    conditional_cdf: Float[Array, "H W1"]
    radiance: Float[Array, "H W C"]


@jax.jit
def envmap_sampler(env: EnvMap) -> EnvSampler:
    """Build the sampling tables of ``env``: P(pixel) proportional to luminance x solid angle.

    A black map (nothing to importance-sample) falls back to uniform over the
    sphere rather than dividing by zero.
    """
    rad = env.radiance
    h, w, c = rad.shape
    dt = widest_float(rad.dtype, jnp.float32)
    if c == 3:
        lum = rad.astype(dt) @ jnp.asarray(_LUMA, dt)
    else:
        lum = jnp.mean(rad.astype(dt), axis=-1)
    dom = latlong_solid_angles(h, w, dt)
    mass = jnp.maximum(lum, 0.0) * dom
    total = jnp.sum(mass)
    mass = jnp.where(total > 0, mass, dom)  # black map: uniform in solid angle
    prob = mass / jnp.sum(mass)
    row_prob = jnp.sum(prob, axis=1)
    marginal = jnp.concatenate([jnp.zeros(1, dt), jnp.cumsum(row_prob)])
    marginal = marginal / marginal[-1]
    row_cdf = jnp.cumsum(prob, axis=1)
    safe = jnp.where(row_cdf[:, -1:] > 0, row_cdf[:, -1:], 1.0)
    conditional = jnp.concatenate([jnp.zeros((h, 1), dt), row_cdf / safe], axis=1)
    # An empty row is never chosen; give it a valid (uniform) CDF anyway.
    uniform = jnp.broadcast_to(jnp.linspace(0.0, 1.0, w + 1, dtype=dt)[None, :], (h, w + 1))
    conditional = jnp.where(row_cdf[:, -1:] > 0, conditional, uniform)
    return EnvSampler(prob, marginal, conditional, rad)


def _pick(cdf: Array, u: Array) -> tuple[Array, Array]:
    """Bin i with cdf[i] <= u < cdf[i+1] (skipping empty bins) and u's position in it."""
    n = cdf.shape[-1] - 1
    i = jnp.clip(jnp.searchsorted(cdf, u, side="right") - 1, 0, n - 1)
    lo, hi = cdf[i], cdf[i + 1]
    width = hi - lo
    frac = jnp.where(width > 0, (u - lo) / jnp.where(width > 0, width, 1.0), 0.5)
    return i, jnp.clip(frac, 0.0, 1.0)


@jax.jit
def sample_envmap(
    sampler: EnvSampler, u: Float[ArrayLike, "N 2"]
) -> tuple[Float[Array, "N 3"], Float[Array, " N"], Float[Array, "N C"], Int[Array, "N 2"]]:
    """Map uniform ``u in [0, 1)^2`` to directions distributed as the sampler's pdf.

    Returns:
        ``(directions [N, 3], pdf [N] per steradian, radiance [N, C], pixel [N, 2] (row, col))``.
        The estimator ``mean(f(d) L(d) / pdf)`` of ``int f L dOmega`` is unbiased.
    """
    u = jnp.asarray(u)
    h, w = sampler.pixel_prob.shape
    dt = sampler.marginal_cdf.dtype
    u = u.astype(dt)
    row, fy = _pick(sampler.marginal_cdf, u[:, 0])
    col, fx = jax.vmap(_pick)(sampler.conditional_cdf[row], u[:, 1])
    # Uniform in solid angle inside the pixel: azimuth linear, cos(theta) linear.
    # The pixel indices enter the angles as floats of the tables' dtype (strict promotion: no int x float).
    row_f, col_f = row.astype(dt), col.astype(dt)
    t0 = jnp.pi * row_f / h
    t1 = jnp.pi * (row_f + 1) / h
    cos_t = jnp.cos(t0) + fy * (jnp.cos(t1) - jnp.cos(t0))
    sin_t = safe_sqrt(1.0 - cos_t * cos_t)  # gradient 0, not inf, at the poles
    phi = 2 * jnp.pi * (col_f + fx) / w - jnp.pi
    d = jnp.stack([sin_t * jnp.sin(phi), cos_t, -sin_t * jnp.cos(phi)], axis=-1)
    dom = latlong_solid_angles(h, w, dt)[row, 0]
    pdf = sampler.pixel_prob[row, col] / dom
    return d, pdf, sampler.radiance[row, col], jnp.stack([row, col], axis=-1)


@jax.jit
def envmap_pdf(sampler: EnvSampler, directions: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch"]:
    """Density per steradian with which :func:`sample_envmap` produces ``directions``."""
    h, w = sampler.pixel_prob.shape
    v, u = direction_to_latlong(directions)
    row = jnp.clip(jnp.floor(v * h).astype(jnp.int32), 0, h - 1)
    col = jnp.clip(jnp.floor(u * w).astype(jnp.int32), 0, w - 1)
    dom = latlong_solid_angles(h, w, sampler.pixel_prob.dtype)[row, 0]
    return sampler.pixel_prob[row, col] / dom
