"""The GGX / Trowbridge-Reitz microfacet distribution (Walter et al. 2007),
anisotropic, with Smith masking and visible-normal sampling (Heitz 2018)."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._base import ParamSpec
from ._distribution import AbstractMicrofacetDistribution, alpha_specs, clamped_alphas, init_alphas, split
from ._safe import dot, safe_div, safe_normalize, safe_sqrt


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

    def _a2s2(self, w):
        # ax^2 x^2 + ay^2 y^2: alpha^2 tan^2(theta) times cos^2(theta)
        ax, ay = clamped_alphas(self.alpha_x, self.alpha_y)
        x, y, z = split(w)
        return (ax * x) ** 2 + (ay * y) ** 2, z

    def D(self, wm: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """GGX density in 1/sr (Walter et al. 2007, eq. 33); 0 for wm_z <= 0."""
        ax, ay = clamped_alphas(self.alpha_x, self.alpha_y)
        x, y, z = split(wm)
        t = (x / ax) ** 2 + (y / ay) ** 2 + z * z
        return jnp.where(z > 0, safe_div(1.0, jnp.pi * ax * ay * t * t), 0.0)

    def Lambda(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Lambda(w) = (sqrt(1 + alpha^2 tan^2) - 1) / 2 (Heitz 2014, eq. 86),
        written as a2s2 / (2 |z| (R + |z|)) with R = sqrt(a2s2 + z^2) so that it has no
        cancellation for smooth surfaces."""
        a2s2, z = self._a2s2(w)
        az = jnp.abs(z)
        r = safe_sqrt(a2s2 + z * z)
        big = jnp.finfo(jnp.result_type(a2s2)).max
        return safe_div(a2s2, 2.0 * az * (r + az), fallback=big)

    def lambda_cos(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """cos(theta) Lambda(w) = (R - z) / 2 = a2s2 / (2 (R + z)); 0 below the horizon."""
        a2s2, z = self._a2s2(w)
        up = z > 0
        r = safe_sqrt(a2s2 + z * z)
        return jnp.where(up, safe_div(a2s2, 2.0 * (r + jnp.where(up, z, 1.0))), 0.0)

    def G1(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Smith masking 2z / (z + R) (Walter et al. 2007, eq. 34); 0 below the horizon."""
        a2s2, z = self._a2s2(w)
        up = z > 0
        zs = jnp.where(up, z, 1.0)
        r = safe_sqrt(a2s2 + zs * zs)
        return jnp.where(up, 2.0 * zs / (zs + r), 0.0)

    def g1_over_cos(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """G1(w) / cos(theta) = 2 / (z + R): tends to 2 / (alpha sin(theta)) at the horizon."""
        a2s2, z = self._a2s2(w)
        up = z > 0
        zs = jnp.where(up, z, 1.0)
        r = safe_sqrt(a2s2 + zs * zs)
        return jnp.where(up, 2.0 / (zs + r), 0.0)

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
