"""The demo's ground-truth material: smooth, skin-like maps over a mesh's UVs,
what ``relight simulate`` (without ``--textures``) and ``relight demo`` shade
their synthetic captures with."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = ["DEMO_F0", "demo_material"]

# The demo material's specular reflectance at normal incidence: about skin's, ((1.4 - 1) / (1.4 + 1))^2 = 0.0278
# (materials.F0_SKIN), rounded as the demo has always used it (docs/RESULTS.md's demo numbers are made with it).
DEMO_F0 = 0.028


def demo_material(surface) -> tuple[Float[Array, "P 3"], Float[Array, "P 1"], Float[Array, "P 1"]]:
    """Ground-truth Lambert + GGX maps that vary smoothly over a surface's UVs.

    Args:
        surface: anything with ``uv`` [P, 2] (a ``stage.Surface``).

    Returns:
        float32 ``(rho_d [P, 3], f0 [P, 1], alpha [P, 1])`` for ``brdf.lambert_ggx``: a skin-like diffuse
        albedo (red 0.62, green 0.42, blue 0.33, each modulated by a few percent), ``f0 = DEMO_F0`` everywhere
        and a GGX roughness varying between 0.2 and 0.5.
    """
    uv = np.asarray(surface.uv, np.float64)
    u, v = uv[:, 0], uv[:, 1]
    rho_d = np.stack([0.62 + 0.08 * np.sin(7 * u) * np.cos(5 * v),
                      0.42 + 0.06 * np.cos(6 * v + 1.0),
                      0.33 + 0.05 * np.sin(4 * u + 3 * v)], axis=1)
    f0 = np.full((len(u), 1), DEMO_F0)
    alpha = 0.35 + 0.15 * np.sin(9 * u + 2.0) * np.sin(7 * v)
    return (jnp.asarray(rho_d, jnp.float32), jnp.asarray(f0, jnp.float32),
            jnp.asarray(alpha[:, None], jnp.float32))
