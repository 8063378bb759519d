"""Lambertian (ideal diffuse) reflection."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._base import AbstractBRDF, ParamSpec, as_param, check_directions, check_param_rank, cos_theta


class Lambert(AbstractBRDF):
    """Ideal diffuse reflection f_r = albedo / pi (Lambert 1760, Photometria; pbrt-v4 §9.2).

    ``albedo`` (unitless, >= 0, [*batch, C] or 0-d) is the directional-hemispherical
    reflectance, the same for every incident direction. Reciprocal; conserves
    energy for albedo <= 1.
    """

    albedo: Float[Array, "*batch C"]

    def __init__(self, albedo: ArrayLike):
        self.albedo = as_param("Lambert", "albedo", albedo, lower=0.0)

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """albedo / pi in 1/sr where both directions are above the horizon, else 0."""
        wi, wo = check_directions("Lambert", wi, wo)
        check_param_rank("Lambert", wi.ndim, albedo=self.albedo)
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        return jnp.where(active, self.albedo / jnp.pi, 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """``albedo`` in (0, 1) through a sigmoid."""
        return {"albedo": ParamSpec(0.0, 1.0, "sigmoid")}
