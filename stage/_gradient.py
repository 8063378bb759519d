"""Spherical gradient illumination (Ma et al. 2007, "Rapid Acquisition of
Specular and Diffuse Normal Maps from Polarized Spherical Gradient
Illumination"), synthesised from an OLAT capture by linearity of light.

The four patterns are the full-on sphere P_f(w) = 1 and the gradients
P_i(w) = (1 + w_i) / 2, i in {x, y, z} (stage frame), Ma et al. eq. 2. Each
light stands for its Voronoi cell: a pattern of radiance P(w) is reproduced by
weighting light l by P(w_l) Omega_l / E_l, where E_l is the light's irradiance
at the rig centre (so the weighted light delivers P(w_l) Omega_l there, the
irradiance from its cell).

For a Lambertian surface, integral of w_i max(n.w, 0) dw = (2 pi / 3) n_i and
integral of max(n.w, 0) dw = pi, so I_i / I_f = 1/2 + n_i / 3 and the diffuse
normal is normalize(2 I_i - I_f) (Ma et al. eq. 4). For a specular lobe the
same ratio gives the reflection vector r; the specular normal is the half
vector normalize(r + wo) (Ma et al. sec. 3.2).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from brdf import safe_normalize

from ._capture import Capture
from ._rig import Rig

PATTERNS = ("full", "x", "y", "z")


def gradient_weights(rig: Rig) -> Float[Array, "4 light channel"]:
    """Weights that turn OLAT images into the full-on, x, y and z spherical gradient images.

    Each weight is the pattern's value at the light x the light's solid angle / its irradiance at the centre.

    Args:
        rig: the light rig.

    Returns:
        Weights [4, L, C] (full, x, y, z).

    References:
        Ma et al. 2007, "Rapid acquisition of specular and diffuse normal maps from polarized spherical gradient
        illumination", sec. 3.
    """
    d = rig.directions
    pattern = jnp.concatenate([jnp.ones((1, rig.num_lights), d.dtype), 0.5 * (1.0 + d.T)], axis=0)  # [4, L]
    return pattern[:, :, None] * (rig.solid_angle[:, None] / rig.center_irradiance)[None]


def gradient_images(capture: Capture) -> Float[Array, "view 4 sample channel"]:
    """The four gradient-illumination images (full, x, y, z) of an OLAT capture: sum over lights of weight x OLAT.

    Args:
        capture: an OLAT capture (radiance [V, L, P, C]).

    Returns:
        Images [V, 4, P, C].

    References:
        Ma et al. 2007, "Rapid acquisition of specular and diffuse normal maps from polarized spherical gradient
        illumination", sec. 3.
    """
    w = gradient_weights(capture.rig).astype(capture.radiance.dtype)
    return jnp.einsum("klc,vlpc->vkpc", w, capture.radiance)


def _ratio_vector(images, channel_weights=None):
    I = jnp.asarray(images)
    if channel_weights is None:
        I = jnp.mean(I, axis=-1)
    else:
        I = jnp.tensordot(I, jnp.asarray(channel_weights, I.dtype), axes=([-1], [0]))
    full = I[..., 0, :]
    g = jnp.stack([I[..., 1, :], I[..., 2, :], I[..., 3, :]], axis=-1)  # [..., P, 3]
    return 2.0 * g - full[..., None]


def diffuse_normals(
    images: Float[Array, "*batch 4 sample channel"], channel_weights=None
) -> Float[Array, "*batch sample 3"]:
    """World-space diffuse normals normalize(2 I_(x,y,z) - I_full) from gradient images.

    Args:
        images: gradient images [*batch, 4, P, C] (full, x, y, z).
        channel_weights: weights [C] of the channels (None: their mean).

    Returns:
        Unit normals [*batch, P, 3]; the zero vector for samples that received no light.

    References:
        Ma et al. 2007, "Rapid acquisition of specular and diffuse normal maps from polarized spherical gradient
        illumination", eq. 4.
    """
    return safe_normalize(_ratio_vector(images, channel_weights))


def specular_normals(images: Float[Array, "*batch 4 sample channel"], wo: Float[Array, "*batch sample 3"],
                     channel_weights=None) -> Float[Array, "*batch sample 3"]:
    """World-space specular normals from specular-only gradient images (parallel minus cross polarised).

    The half vector between the reflection vector normalize(2 I_i - I_full) and the view direction.

    Args:
        images: specular gradient images [*batch, 4, P, C] (full, x, y, z).
        wo: unit world directions toward the camera [*batch, P, 3].
        channel_weights: weights [C] of the channels (None: their mean).

    Returns:
        Unit normals [*batch, P, 3].

    References:
        Ma et al. 2007, "Rapid acquisition of specular and diffuse normal maps from polarized spherical gradient
        illumination", sec. 3.2.
    """
    r = safe_normalize(_ratio_vector(images, channel_weights))
    return safe_normalize(r + jnp.asarray(wo))
