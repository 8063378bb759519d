"""Orthonormal frames about a normal: the branchless basis of Duff et al. 2017
for any direction, and Gram-Schmidt against a tangent guess (mesh UV
tangents) with a fallback where the guess is degenerate.

A frame (t, b, n) is right-handed, t x b = n; its rows form the rotation from
the frame it was built in to the local shading frame (z = n):
w_local = (w.t, w.b, w.n).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

# Below this length the tangent guess minus its normal part carries no usable
# direction (a degenerate UV chart: dP/du parallel to n or zero); the value
# stage's texel sampler has always used.
_TANGENT_MIN = 1e-8
# |n_x| below this: the fallback tangent starts from x, else from y, which is
# then at least sqrt(1 - 0.9^2) = 0.44 away from n, so the projection never vanishes.
_FALLBACK_SWITCH = 0.9


def orthonormal_basis(n: Float[ArrayLike, "*batch 3"]) -> tuple[Float[Array, "*batch 3"], Float[Array, "*batch 3"]]:
    """A right-handed tangent and bitangent (t, b) for unit normals n, by a branchless construction.

        s = sign(n_z), a = -1 / (s + n_z), c = n_x n_y a
        t = (1 + s n_x^2 a, s c, -s n_x),   b = (c, s + n_y^2 a, -n_y)

    Continuous everywhere except across n_z = 0 and accurate up to n = (0, 0, -1) (|s + n_z| >= 1, so no division
    by a small number and finite gradients everywhere; sign(0) = +1, also for -0.0). The basis is some rotation
    about n, not a chosen tangent: use ``frame_from_normal_tangent`` for that. JAX (NumPy input is converted).

    Args:
        n: unit normals [*batch, 3].

    Returns:
        (t, b), each [*batch, 3], unit and orthogonal to each other and to n, with t x b = n.

    References:
        Duff, Burgess, Christensen, Hery, Kensler, Liani and Villemin 2017, "Building an orthonormal basis,
        revisited", JCGT 6(1) (the revised branchless listing).
    """
    n = jnp.asarray(n)
    x, y, z = n[..., 0:1], n[..., 1:2], n[..., 2:3]
    sign = jnp.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    c = x * y * a
    t = jnp.concatenate([1.0 + sign * x * x * a, sign * c, -sign * x], axis=-1)
    b = jnp.concatenate([c, sign + y * y * a, -y], axis=-1)
    return t, b


def frame_from_normal_tangent(
    n: Float[ArrayLike, "*batch 3"], t_guess: Float[ArrayLike, "*batch 3"]
) -> tuple[Float[ArrayLike, "*batch 3"], Float[ArrayLike, "*batch 3"]]:
    """The right-handed orthonormal frame (t, b, n) whose tangent is ``t_guess`` made orthogonal to ``n``.

    Gram-Schmidt: t = normalize(t_guess - n (n.t_guess)), b = n x t. Where the guess is degenerate
    (|t_guess - n (n.t_guess)| < 1e-8: a UV chart without a tangent) any tangent will do, and the one taken is x
    (or y where |n_x| >= 0.9) made orthogonal to n the same way. NumPy arrays in, NumPy out (stage runs it on host
    arrays); a JAX array for either input uses jax.numpy, with finite gradients (the fallback is selected by a
    mask, and the vector normalised is never near zero for unit n).

    Args:
        n: unit normals [*batch, 3].
        t_guess: tangent guesses [*batch, 3].

    Returns:
        (t, b), each [*batch, 3].
    """
    xp = jnp if isinstance(n, jax.Array) or isinstance(t_guess, jax.Array) else np
    n = xp.asarray(n)
    t_guess = xp.asarray(t_guess)
    t = t_guess - n * xp.sum(n * t_guess, axis=-1, keepdims=True)
    bad = xp.linalg.norm(t, axis=-1, keepdims=True) < _TANGENT_MIN
    use_x = xp.abs(n[..., 0:1]) < _FALLBACK_SWITCH
    one, zero = xp.ones_like(n[..., 0:1]), xp.zeros_like(n[..., 0:1])
    alt = xp.concatenate([xp.where(use_x, one, zero), xp.where(use_x, zero, one), zero], axis=-1)
    t_alt = alt - n * xp.sum(n * alt, axis=-1, keepdims=True)
    t = xp.where(bad, t_alt, t)
    t = t / xp.linalg.norm(t, axis=-1, keepdims=True)
    b = xp.cross(n, t)
    return t, b
