"""Hemisphere sampling with densities: cosine-weighted (Malley's method over
Shirley & Chiu's concentric disk) and uniform."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from ._base import cos_theta
from ._safe import safe_div, safe_sqrt


def sample_concentric_disk(u: Float[Array, "*batch 2"]) -> Float[Array, "*batch 2"]:
    """Uniform point on the unit disk from two uniforms in [0, 1), by Shirley &
    Chiu 1997's concentric map (area preserving, low distortion; pbrt-v4 §A.5.1)."""
    a = 2.0 * u[..., 0:1] - 1.0
    b = 2.0 * u[..., 1:2] - 1.0
    first = jnp.abs(a) > jnp.abs(b)
    r = jnp.where(first, a, b)
    # theta = pi/4 * b/a or pi/2 - pi/4 * a/b; the ratio's lane with a zero divisor is not taken.
    phi = jnp.where(first, jnp.pi / 4 * safe_div(b, a), jnp.pi / 2 - jnp.pi / 4 * safe_div(a, b))
    return jnp.concatenate([r * jnp.cos(phi), r * jnp.sin(phi)], axis=-1)


def sample_cosine_hemisphere(u: Float[Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
    """Direction with density cos(theta)/pi over the upper hemisphere (Malley's
    method: a uniform disk point lifted to the hemisphere; pbrt-v4 §A.5.3)."""
    d = sample_concentric_disk(u)
    z = safe_sqrt(1.0 - d[..., 0:1] ** 2 - d[..., 1:2] ** 2)
    return jnp.concatenate([d, z], axis=-1)


def pdf_cosine_hemisphere(w: Float[Array, "*batch 3"]) -> Float[Array, "*batch 1"]:
    """cos(theta)/pi in 1/sr above the horizon, 0 below."""
    return jnp.maximum(cos_theta(w), 0.0) / jnp.pi


def sample_uniform_hemisphere(u: Float[Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
    """Direction with density 1/(2 pi) over the upper hemisphere (z = u0)."""
    z = u[..., 0:1]
    r = safe_sqrt(1.0 - z * z)
    phi = 2.0 * jnp.pi * u[..., 1:2]
    return jnp.concatenate([r * jnp.cos(phi), r * jnp.sin(phi), z], axis=-1)


def pdf_uniform_hemisphere(w: Float[Array, "*batch 3"]) -> Float[Array, "*batch 1"]:
    """1/(2 pi) in 1/sr above the horizon, 0 below."""
    return jnp.where(cos_theta(w) > 0, 1.0 / (2.0 * jnp.pi), 0.0)
