"""Real spherical harmonics on the sphere of world directions: basis, projection
of an environment map, reconstruction, and irradiance by Ramamoorthi &
Hanrahan 2001 ("An Efficient Representation for Irradiance Environment Maps").

Basis: the standard real, orthonormal SH without the Condon-Shortley phase
(the convention of Ramamoorthi & Hanrahan's eq. 3 constants: Y_00 = 0.282095,
Y_1{-1,0,1} = 0.488603 {y, z, x}, ...), evaluated on the world coordinates
(x, y, z) of the light-stage frame. The polar axis of the basis is therefore
world z, not the frame's "up" (y); that does not matter for anything here,
because irradiance is a convolution with a zonal kernel and acts on each band
as a whole (Funk-Hecke), whatever the basis' orientation.

Index of (l, m), -l <= m <= l: ``k = l * l + l + m`` (order L has (L+1)^2 terms).
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from brdf import widest_float

from ._latlong import EnvMap, latlong_directions, latlong_solid_angles

__all__ = [
    "sh_basis",
    "sh_index",
    "sh_irradiance",
    "sh_irradiance_kernel",
    "sh_project",
    "sh_reconstruct",
]


def sh_index(l: int, m: int) -> int:
    """Flat index ``l * l + l + m`` of the real spherical harmonic (l, m).

    Args:
        l: band, >= 0.
        m: order, in [-l, l].

    Returns:
        The index into a ``[(order+1)^2, ...]`` coefficient array.
    """
    if not -l <= m <= l:
        raise ValueError(f"SH index needs -l <= m <= l, got l={l}, m={m}")
    return l * l + l + m


def _norm(l: int, m: int) -> float:
    """K_l^m = sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!), times sqrt(2) for m != 0."""
    k = math.sqrt((2 * l + 1) / (4 * math.pi) * math.factorial(l - m) / math.factorial(l + m))
    return k * (math.sqrt(2.0) if m else 1.0)


@functools.partial(jax.jit, static_argnames=('order',))
def sh_basis(directions: Float[ArrayLike, "*batch 3"], order: int) -> Float[Array, "*batch K"]:
    """Every real spherical harmonic up to band ``order`` at unit ``directions``.

    Uses P_l^m(z) = (1 - z^2)^(m/2) Q_l^m(z) and (1 - z^2)^(m/2) (cos, sin)(m phi) = (Re, Im)(x + i y)^m, so the
    basis is a polynomial in (x, y, z): no atan2, no singularity at the poles, smooth gradients everywhere.
    Q obeys Q_m^m = (2m-1)!!, Q_{m+1}^m = (2m+1) z Q_m^m, (l-m) Q_l^m = (2l-1) z Q_{l-1}^m - (l+m-1) Q_{l-2}^m.

    Args:
        directions: unit vectors [*batch, 3].
        order: the highest band, >= 0.

    Returns:
        Y [*batch, (order+1)^2], indexed by ``sh_index(l, m)``.
    """
    if order < 0:
        raise ValueError(f"SH order must be >= 0, got {order}")
    d = jnp.asarray(directions)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    out: list = [None] * ((order + 1) ** 2)
    cos_m, sin_m = jnp.ones_like(x), jnp.zeros_like(x)  # Re, Im of (x + i y)^m
    for m in range(order + 1):
        if m > 0:
            cos_m, sin_m = x * cos_m - y * sin_m, x * sin_m + y * cos_m
        q_mm = float(np.prod(np.arange(1, 2 * m, 2))) if m else 1.0  # (2m-1)!!
        q_prev2, q_prev = None, jnp.full_like(z, q_mm)
        for l in range(m, order + 1):
            if l == m:
                q = q_prev
            elif l == m + 1:
                q = (2 * m + 1) * z * q_prev
            else:
                q = ((2 * l - 1) * z * q_prev - (l + m - 1) * q_prev2) / (l - m)
            if l > m:
                q_prev2, q_prev = q_prev, q
            k = _norm(l, m)
            if m == 0:
                out[sh_index(l, 0)] = k * q
            else:
                out[sh_index(l, m)] = k * q * cos_m
                out[sh_index(l, -m)] = k * q * sin_m
    return jnp.stack(out, axis=-1)


@functools.partial(jax.jit, static_argnums=1)
def _project(radiance: Array, order: int) -> Array:
    h, w, c = radiance.shape
    dt = widest_float(radiance.dtype, jnp.float32)
    dirs = latlong_directions(h, w, dt)  # [H, W, 3]
    weighted = radiance.astype(dt) * latlong_solid_angles(h, w, dt)[..., None]  # L dOmega

    # Row by row keeps the [W, K] basis block small for high orders.
    def row(acc, xs):
        d_row, l_row = xs
        return acc + sh_basis(d_row, order).T @ l_row, None

    acc, _ = jax.lax.scan(row, jnp.zeros(((order + 1) ** 2, c), dt), (dirs, weighted))
    return acc


def sh_project(env: EnvMap, order: int = 2) -> Float[Array, "K C"]:
    """Spherical-harmonic coefficients L_lm = sum_pixels L(d) Y_lm(d) dOmega of a lat-long map.

    The exact projection of the piecewise-constant map sampled at pixel centres.

    Args:
        env: a lat-long environment map (radiance [H, W, C]).
        order: the highest band.

    Returns:
        Coefficients [(order+1)^2, C].
    """
    return _project(env.radiance, int(order))


@jax.jit
def sh_reconstruct(
    coeffs: Float[ArrayLike, "K C"], directions: Float[ArrayLike, "*batch 3"]
) -> Float[Array, "*batch C"]:
    """The band-limited map sum_k coeffs[k] Y_k(d) at ``directions``.

    Args:
        coeffs: spherical-harmonic coefficients [K, C], K = (order+1)^2.
        directions: unit vectors [*batch, 3].

    Returns:
        Radiance [*batch, C].
    """
    coeffs = jnp.asarray(coeffs)
    order = _order_of(coeffs.shape[0])
    return sh_basis(directions, order) @ coeffs


def _order_of(k: int) -> int:
    order = int(round(math.sqrt(k))) - 1
    if (order + 1) ** 2 != k:
        raise ValueError(f"{k} SH coefficients is not (order + 1)^2 for any order")
    return order


def sh_irradiance_kernel(order: int) -> np.ndarray:
    """The clamped-cosine kernel's spherical-harmonic coefficients A_hat_l, l = 0..order.

    A_0 = pi, A_1 = 2 pi / 3, A_l = 0 for odd l > 1, and for even l
    A_l = 2 pi (-1)^(l/2 - 1) / ((l + 2)(l - 1)) * l! / (2^l ((l/2)!)^2).

    Args:
        order: the highest band.

    Returns:
        A_hat [order + 1] (NumPy, float64).

    References:
        Ramamoorthi & Hanrahan 2001, "An efficient representation for irradiance environment maps", eq. 8-9.
    """
    out = np.zeros(order + 1)
    for l in range(order + 1):
        if l == 0:
            out[l] = math.pi
        elif l == 1:
            out[l] = 2 * math.pi / 3
        elif l % 2 == 0:
            out[l] = (
                2 * math.pi * (-1) ** (l // 2 - 1) / ((l + 2) * (l - 1))
                * math.factorial(l) / (2**l * math.factorial(l // 2) ** 2)
            )
    return out


@functools.partial(jax.jit, static_argnames=('order',))
def sh_irradiance(
    coeffs: Float[ArrayLike, "K C"], normals: Float[ArrayLike, "*batch 3"], order: int = 2
) -> Float[Array, "*batch C"]:
    """Irradiance E(n) = sum_(l <= order) A_hat_l sum_m L_lm Y_lm(n) from a map's SH coefficients.

    The default order 2 is the nine-coefficient method. For any non-negative map,
    |E - E_order2| <= (3/32) x the integral of L over the sphere: the clamped cosine max(0, t) and its band-2
    truncation 1/4 + t/2 + (15 t^2 - 5)/32 differ by at most 3/32 (at grazing, t = 0).

    Args:
        coeffs: the map's coefficients [K, C] (``sh_project``), K >= (order+1)^2.
        normals: unit surface normals [*batch, 3].
        order: the highest band used.

    Returns:
        Irradiance [*batch, C] (radiance x sr).

    References:
        Ramamoorthi & Hanrahan 2001, "An efficient representation for irradiance environment maps", eq. 7.
    """
    coeffs = jnp.asarray(coeffs)
    available = _order_of(coeffs.shape[0])
    if order > available:
        raise ValueError(f"irradiance of order {order} needs {(order + 1) ** 2} SH coefficients, got {coeffs.shape[0]}")
    kernel = sh_irradiance_kernel(order)
    scale = np.concatenate([np.full(2 * l + 1, kernel[l]) for l in range(order + 1)])
    c = coeffs[: (order + 1) ** 2] * jnp.asarray(scale, coeffs.dtype)[:, None]
    return sh_basis(normals, order).astype(c.dtype) @ c
