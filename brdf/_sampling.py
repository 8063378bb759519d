"""Hemisphere sampling with densities: cosine-weighted (Malley's method over
Shirley & Chiu's concentric disk) and uniform; and the deterministic
Fibonacci point sets (rigs, ambient-occlusion rays) that the stage and the
renderer share."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._base import cos_theta
from ._safe import safe_div, safe_sqrt


def sample_concentric_disk(u: Float[Array, "*batch 2"]) -> Float[Array, "*batch 2"]:
    """A uniform point on the unit disk from two uniforms, by the concentric map (area preserving, low distortion).

    Args:
        u: uniforms in [0, 1), [*batch, 2].

    Returns:
        Points [*batch, 2] on the unit disk.

    References:
        Shirley & Chiu 1997, "A low distortion map between disk and square"; pbrt-v4, sec. A.5.1.
    """
    a = 2.0 * u[..., 0:1] - 1.0
    b = 2.0 * u[..., 1:2] - 1.0
    first = jnp.abs(a) > jnp.abs(b)
    r = jnp.where(first, a, b)
    # theta = pi/4 * b/a or pi/2 - pi/4 * a/b; the ratio's lane with a zero divisor is not taken.
    phi = jnp.where(first, jnp.pi / 4 * safe_div(b, a), jnp.pi / 2 - jnp.pi / 4 * safe_div(a, b))
    return jnp.concatenate([r * jnp.cos(phi), r * jnp.sin(phi)], axis=-1)


def sample_cosine_hemisphere(u: Float[Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
    """A direction with density cos(theta) / pi over the upper hemisphere (Malley's method).

    A uniform disk point lifted to the hemisphere.

    Args:
        u: uniforms in [0, 1), [*batch, 2].

    Returns:
        Unit directions [*batch, 3] with z >= 0.

    References:
        pbrt-v4, sec. A.5.3.
    """
    d = sample_concentric_disk(u)
    z = safe_sqrt(1.0 - d[..., 0:1] ** 2 - d[..., 1:2] ** 2)
    return jnp.concatenate([d, z], axis=-1)


def pdf_cosine_hemisphere(w: Float[Array, "*batch 3"]) -> Float[Array, "*batch 1"]:
    """The density cos(theta) / pi of ``sample_cosine_hemisphere``.

    Args:
        w: unit directions [*batch, 3].

    Returns:
        The density in 1/sr, [*batch, 1]; 0 below the horizon.
    """
    return jnp.maximum(cos_theta(w), 0.0) / jnp.pi


def sample_uniform_hemisphere(u: Float[Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
    """A direction with density 1 / (2 pi) over the upper hemisphere (z = u0).

    Args:
        u: uniforms in [0, 1), [*batch, 2].

    Returns:
        Unit directions [*batch, 3] with z >= 0.
    """
    z = u[..., 0:1]
    r = safe_sqrt(1.0 - z * z)
    phi = 2.0 * jnp.pi * u[..., 1:2]
    return jnp.concatenate([r * jnp.cos(phi), r * jnp.sin(phi), z], axis=-1)


def pdf_uniform_hemisphere(w: Float[Array, "*batch 3"]) -> Float[Array, "*batch 1"]:
    """The density 1 / (2 pi) of ``sample_uniform_hemisphere``.

    Args:
        w: unit directions [*batch, 3].

    Returns:
        The density in 1/sr, [*batch, 1]; 0 below the horizon.
    """
    return jnp.where(cos_theta(w) > 0, 1.0 / (2.0 * jnp.pi), 0.0)


# The golden ratio of the Fibonacci lattice, (1 + sqrt 5) / 2, written as stage's rig had it.
_GOLDEN = (1 + 5**0.5) / 2


def fibonacci_sphere(n: int, axis: int = 2, hemisphere: bool = False) -> Float[np.ndarray, "n 3"]:
    """``n`` nearly uniform unit directions on a Fibonacci (golden-angle) spiral (float64 NumPy, built on the host).

    The variant for any n with the points at the centres of n equal-area bands:

        c_k = 1 - (2k + 1) / n,   phi_k = 2 pi k / golden,   k = 0 .. n - 1

    with c_k the component along the pole ``axis`` and (sqrt(1 - c^2) cos phi, sqrt(1 - c^2) sin phi) the other
    two components in increasing index order. Point k covers the equal-area band around c_k, so each point stands
    for 4 pi / n sr (2 pi / n with ``hemisphere``). ``fibonacci_sphere(n, axis=1)`` is exactly the ordering and
    rounding of ``stage.fibonacci_sphere`` (the y pole).

    Args:
        n: the number of directions.
        axis: the pole (0, 1 or 2; 2 = the shading normal).
        hemisphere: cover only the upper half (c_k = 1 - (k + 0.5) / n > 0).

    Returns:
        Unit directions [n, 3].

    References:
        Gonzalez 2010, "Measurement of areas on a sphere using Fibonacci and latitude-longitude lattices",
        Math. Geosci. 42.
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"fibonacci_sphere needs n >= 1 points, got {n}")
    if axis not in (0, 1, 2):
        raise ValueError(f"fibonacci_sphere: axis must be 0, 1 or 2, got {axis!r}")
    k = np.arange(n, dtype=np.float64)
    c = 1 - (k + 0.5) / n if hemisphere else 1 - (2 * k + 1) / n
    r = np.sqrt(np.maximum(1 - c * c, 0))
    phi = 2 * np.pi * k / _GOLDEN
    u, v = r * np.cos(phi), r * np.sin(phi)
    cols = [u, v]
    cols.insert(axis, c)
    return np.stack(cols, axis=1)


def fibonacci_hemisphere(n: int, axis: int = 2) -> Float[np.ndarray, "n 3"]:
    """``n`` nearly uniform unit directions on the upper hemisphere: ``fibonacci_sphere(n, axis, hemisphere=True)``.

    Args:
        n: the number of directions; each stands for 2 pi / n sr.
        axis: the pole (default 2, the shading normal z).

    Returns:
        Unit directions [n, 3].
    """
    return fibonacci_sphere(n, axis, hemisphere=True)
