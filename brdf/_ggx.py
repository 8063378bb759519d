"""The GGX / Trowbridge-Reitz microfacet distribution (Walter et al. 2007),
anisotropic, with Smith masking and visible-normal sampling (Heitz 2018).

The physics lives in the free kernels below (pbrt-v4's
``TrowbridgeReitzDistribution`` split into small functions); :class:`GGX`
holds the roughness and calls them. Each kernel is written once on separate
components, ``ggx_*_xyz(x, y, z, alpha_x, alpha_y)``, so that it serves both
layouts:

- last-axis vectors (Modules): ``ggx_d(wm, alpha_x, alpha_y)`` with
  ``wm`` [*batch, 3] and alphas [*batch, C], [*batch, 1] or 0-d gives [*batch, C];
- component-major arrays (the fitter): ``ggx_d_xyz(*wm, alpha_x, alpha_y)`` with
  ``wm`` [3, N] (rows x, y, z) and 0-d or [N] alphas gives [N].

Directions are unit vectors in the shading frame (z = normal). Roughness is
clamped to ALPHA_MIN (gradient 0 below); ``alpha_y`` None means isotropic
(alpha_y = alpha_x).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._base import ParamSpec
from ._distribution import AbstractMicrofacetDistribution, alpha_specs, clamped_alphas, init_alphas, split
from ._safe import dot, safe_div, safe_normalize, safe_sqrt


def _a2s2(x, y, alpha_x, alpha_y):
    # ax^2 x^2 + ay^2 y^2: alpha^2 tan^2(theta) times cos^2(theta)
    ax, ay = clamped_alphas(alpha_x, alpha_y)
    return (ax * x) ** 2 + (ay * y) ** 2


def ggx_d_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """GGX density of microfacet normals D(wm), for wm = (x, y, z) given as separate components.

    D(wm) = 1 / (pi ax ay ((x/ax)^2 + (y/ay)^2 + z^2)^2), normalised so that integral D(wm) cos(theta_m) dwm = 1;
    its peak, 1/(pi ax ay) at wm = n, stays finite in float32 at ALPHA_MIN.

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        D in 1/sr, the broadcast shape; 0 for z <= 0.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eq. 33; the anisotropic
        form as in Heitz 2014, "Understanding the masking-shadowing function in microfacet-based BRDFs", JCGT 3(2).
    """
    ax, ay = clamped_alphas(alpha_x, alpha_y)
    t = (x / ax) ** 2 + (y / ay) ** 2 + z * z
    return jnp.where(z > 0, safe_div(1.0, jnp.pi * ax * ay * t * t), 0.0)


def ggx_lambda_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """Smith's auxiliary function Lambda(w) = (sqrt(1 + alpha^2 tan^2(theta)) - 1) / 2 for GGX.

    Evaluated as a2s2 / (2 |z| (R + |z|)), a2s2 = (ax x)^2 + (ay y)^2, R = sqrt(a2s2 + z^2), which has no
    cancellation for smooth surfaces. Depends on |z| (either hemisphere).

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        Lambda >= 0 (unitless), the broadcast shape; at the horizon (z = 0), where it is infinite, the largest
        finite number of the dtype.

    References:
        Heitz 2014, "Understanding the masking-shadowing function in microfacet-based BRDFs", JCGT 3(2), eq. 86.
    """
    a2s2 = _a2s2(x, y, alpha_x, alpha_y)
    az = jnp.abs(z)
    r = safe_sqrt(a2s2 + z * z)
    big = jnp.finfo(jnp.result_type(a2s2)).max
    return safe_div(a2s2, 2.0 * az * (r + az), fallback=big)


def ggx_lambda_cos_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """cos(theta) Lambda(w) = (R - z) / 2 = a2s2 / (2 (R + z)) for GGX, finite at the horizon.

    The form the height-correlated Smith term needs; alpha sin(theta) / 2 at the horizon.

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        cos(theta) Lambda(w) (unitless), the broadcast shape; 0 for z <= 0.

    References:
        Heitz 2014, JCGT 3(2), eq. 86 multiplied by cos(theta); used in eq. 99.
    """
    a2s2 = _a2s2(x, y, alpha_x, alpha_y)
    up = z > 0
    r = safe_sqrt(a2s2 + z * z)
    return jnp.where(up, safe_div(a2s2, 2.0 * (r + jnp.where(up, z, 1.0))), 0.0)


def ggx_g1_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """Smith masking G1(w) = 1 / (1 + Lambda(w)) = 2 z / (z + R) for GGX, R = sqrt((ax x)^2 + (ay y)^2 + z^2).

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        G1 in [0, 1] (unitless), the broadcast shape; 1 at normal incidence, 0 for z <= 0.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eq. 34.
    """
    a2s2 = _a2s2(x, y, alpha_x, alpha_y)
    up = z > 0
    zs = jnp.where(up, z, 1.0)
    r = safe_sqrt(a2s2 + zs * zs)
    return jnp.where(up, 2.0 * zs / (zs + r), 0.0)


def ggx_g1_over_cos_xyz(
    x: Float[ArrayLike, "*#shape"],
    y: Float[ArrayLike, "*#shape"],
    z: Float[ArrayLike, "*#shape"],
    alpha_x: Float[ArrayLike, "*#shape"],
    alpha_y: Float[ArrayLike, "*#shape"] | None = None,
) -> Float[Array, "*shape"]:
    """G1(w) / cos(theta) = 2 / (z + R) for GGX, finite at the horizon (2 / (alpha sin(theta)) there).

    The separable Smith term of a microfacet BRDF is 0.25 G1/cos(wi) G1/cos(wo) (``smith_g2_separable_over_cos``).

    Args:
        x, y, z: components of a unit direction in the shading frame (z = normal); any broadcastable shapes.
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic, alpha_x);
            clamped to [ALPHA_MIN, 1].

    Returns:
        G1 / cos(theta) (unitless), the broadcast shape; 0 for z <= 0.

    References:
        Walter et al. 2007, eq. 34 divided by cos(theta).
    """
    a2s2 = _a2s2(x, y, alpha_x, alpha_y)
    up = z > 0
    zs = jnp.where(up, z, 1.0)
    r = safe_sqrt(a2s2 + zs * zs)
    return jnp.where(up, 2.0 / (zs + r), 0.0)


def ggx_d(
    wm: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """GGX density of microfacet normals D(wm) for last-axis vectors (``ggx_d_xyz``).

    Args:
        wm: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        D in 1/sr, [*batch, C]; 0 for wm_z <= 0.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eq. 33.
    """
    return ggx_d_xyz(*split(wm), alpha_x, alpha_y)


def ggx_lambda(
    w: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """Smith's auxiliary function Lambda(w) of GGX for last-axis vectors (``ggx_lambda_xyz``).

    Args:
        w: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        Lambda >= 0, [*batch, C]; the dtype's largest finite number at the horizon.

    References:
        Heitz 2014, "Understanding the masking-shadowing function in microfacet-based BRDFs", JCGT 3(2), eq. 86.
    """
    return ggx_lambda_xyz(*split(w), alpha_x, alpha_y)


def ggx_lambda_cos(
    w: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """cos(theta) Lambda(w) of GGX for last-axis vectors (``ggx_lambda_cos_xyz``).

    Args:
        w: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        cos(theta) Lambda(w), [*batch, C]; 0 below the horizon.

    References:
        Heitz 2014, JCGT 3(2), eq. 86 multiplied by cos(theta).
    """
    return ggx_lambda_cos_xyz(*split(w), alpha_x, alpha_y)


def ggx_g1(
    w: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """Smith masking G1(w) of GGX for last-axis vectors (``ggx_g1_xyz``).

    Args:
        w: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        G1 in [0, 1], [*batch, C]; 0 below the horizon.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eq. 34.
    """
    return ggx_g1_xyz(*split(w), alpha_x, alpha_y)


def ggx_g1_over_cos(
    w: Float[Array, "*batch 3"], alpha_x: ArrayLike, alpha_y: ArrayLike | None = None
) -> Float[Array, "*batch C"]:
    """G1(w) / cos(theta) = 2 / (z + R) of GGX for last-axis vectors (``ggx_g1_over_cos_xyz``).

    Args:
        w: unit directions [*batch, 3] in the shading frame (z = normal).
        alpha_x, alpha_y: roughness along the tangent and the bitangent (alpha_y None: isotropic), broadcast
            against [*batch, C]; clamped to [ALPHA_MIN, 1].

    Returns:
        G1 / cos(theta), [*batch, C]; 0 below the horizon.

    References:
        Walter et al. 2007, eq. 34 divided by cos(theta).
    """
    return ggx_g1_over_cos_xyz(*split(w), alpha_x, alpha_y)


class GGX(AbstractMicrofacetDistribution):
    """GGX (Trowbridge-Reitz) distribution of microfacet normals.

    D(wm) = 1 / (pi ax ay ((x/ax)^2 + (y/ay)^2 + z^2)^2) for unit wm (Walter et al.
    2007, eq. 33; anisotropic form as in Heitz 2014, JCGT 3(2)). ``alpha_x``, ``alpha_y``
    are roughnesses along the tangent and bitangent (unitless, >= 0, clamped to
    ALPHA_MIN in evaluation); isotropic when ``alpha_y`` is None.
    """

    alpha_x: Float[Array, "*batch C"]
    alpha_y: Float[Array, "*batch C"] | None

    def __init__(self, alpha_x: ArrayLike, alpha_y: ArrayLike | None = None):
        self.alpha_x, self.alpha_y = init_alphas("GGX", alpha_x, alpha_y)

    def D(self, wm: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """GGX density in 1/sr (Walter et al. 2007, eq. 33); 0 for wm_z <= 0. See :func:`ggx_d`."""
        return ggx_d(wm, self.alpha_x, self.alpha_y)

    def Lambda(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Lambda(w) = (sqrt(1 + alpha^2 tan^2) - 1) / 2 (Heitz 2014, eq. 86). See :func:`ggx_lambda`."""
        return ggx_lambda(w, self.alpha_x, self.alpha_y)

    def lambda_cos(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """cos(theta) Lambda(w) = (R - z) / 2; 0 below the horizon. See :func:`ggx_lambda_cos`."""
        return ggx_lambda_cos(w, self.alpha_x, self.alpha_y)

    def G1(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Smith masking 2z / (z + R) (Walter et al. 2007, eq. 34); 0 below the horizon. See :func:`ggx_g1`."""
        return ggx_g1(w, self.alpha_x, self.alpha_y)

    def g1_over_cos(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """G1(w) / cos(theta) = 2 / (z + R). See :func:`ggx_g1_over_cos`."""
        return ggx_g1_over_cos(w, self.alpha_x, self.alpha_y)

    def sample_wm(self, wo: Float[Array, "*batch 3"], u: Float[Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
        """A visible normal (density D_wo(wm) = G1(wo) max(0, wo.wm) D(wm) / cos(theta_o))
        by Heitz 2018, "Sampling the GGX distribution of visible normals", JCGT 7(4),
        appendix A (the hemisphere-split disk warp)."""
        ax, ay = clamped_alphas(self.alpha_x, self.alpha_y)
        x, y, z = split(wo)
        # The view direction stretched to the hemisphere configuration, and an orthonormal basis.
        vh = safe_normalize(jnp.concatenate(jnp.broadcast_arrays(ax * x, ay * y, z), axis=-1))
        vx, vy, vz = split(vh)
        lensq = vx * vx + vy * vy
        ok = lensq > 0
        inv = jnp.where(ok, 1.0 / jnp.sqrt(jnp.where(ok, lensq, 1.0)), 0.0)
        zero = jnp.zeros_like(vx)
        t1 = jnp.concatenate(
            [jnp.where(ok, -vy * inv, 1.0), jnp.where(ok, vx * inv, 0.0), zero], axis=-1
        )
        t2 = jnp.cross(vh, t1)
        # A point on the projected disk, warped onto the visible half.
        r = safe_sqrt(u[..., 0:1])
        phi = 2.0 * jnp.pi * u[..., 1:2]
        p1 = r * jnp.cos(phi)
        p2 = r * jnp.sin(phi)
        s = 0.5 * (1.0 + vz)
        p2 = (1.0 - s) * safe_sqrt(1.0 - p1 * p1) + s * p2
        # Reprojection onto the hemisphere, then unstretched back to the ellipsoid.
        nh = p1 * t1 + p2 * t2 + safe_sqrt(1.0 - p1 * p1 - p2 * p2) * vh
        nx, ny, nz = split(nh)
        ne = jnp.concatenate(jnp.broadcast_arrays(ax * nx, ay * ny, jnp.maximum(nz, 0.0)), axis=-1)
        return safe_normalize(ne)

    def pdf_wm(self, wo: Float[Array, "*batch 3"], wm: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """D_wo(wm) = G1(wo) max(0, wo.wm) D(wm) / cos(theta_o) (Heitz 2018, §2), in 1/sr."""
        wo_wm = jnp.maximum(dot(wo, wm), 0.0)
        return self.g1_over_cos(wo) * wo_wm * self.D(wm)

    def fittable(self) -> dict[str, ParamSpec]:
        """``alpha_x`` (and ``alpha_y`` when anisotropic) in (ALPHA_MIN, 1), sigmoid."""
        return alpha_specs(self.alpha_y)
