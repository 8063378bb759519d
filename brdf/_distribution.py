"""The interface of a microfacet normal distribution, and helpers shared by
GGX and Beckmann."""

from __future__ import annotations

import abc

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._base import ParamSpec, as_param

# The model's own roughness floor, shared by GGX and Beckmann (pbrt-v4 uses the
# same 1e-4): the peak of D is 1/(pi alpha^2) ~ 3e7 there, and alpha^4 = 1e-16
# stays far from float32 underflow, so values and gradients stay finite in
# float32. It is not the fitter's prior: a rig with L lights resolves far less.
ALPHA_MIN = 1e-4


class AbstractMicrofacetDistribution(eqx.Module):
    """A distribution of microfacet normals D(wm) with Smith's masking.

    Normalised so that the projected area is one: integral D(wm) cos(theta_m) dwm = 1.
    Directions are unit vectors in the shading frame; outputs have a channel axis.
    """

    @abc.abstractmethod
    def D(self, wm: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Density of microfacet normals, in 1/sr; 0 for wm below the horizon."""

    @abc.abstractmethod
    def Lambda(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Smith's auxiliary function Lambda(w) (Heitz 2014), >= 0; a very large
        finite number at the horizon, where it is infinite."""

    @abc.abstractmethod
    def G1(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Smith masking G1(w) = 1 / (1 + Lambda(w)) for w above the horizon, else 0."""

    @abc.abstractmethod
    def g1_over_cos(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """G1(w) / cos(theta), finite as cos(theta) -> 0; 0 below the horizon."""

    @abc.abstractmethod
    def lambda_cos(self, w: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """cos(theta) * Lambda(w) for w above the horizon, finite at the horizon; 0 below."""

    @abc.abstractmethod
    def sample_wm(self, wo: Float[Array, "*batch 3"], u: Float[Array, "*batch 2"]) -> Float[Array, "*batch 3"]:
        """A microfacet normal drawn from ``pdf_wm(wo, .)`` using two uniforms in [0, 1)."""

    @abc.abstractmethod
    def pdf_wm(self, wo: Float[Array, "*batch 3"], wm: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Density (1/sr, over microfacet normals) of ``sample_wm``."""

    @abc.abstractmethod
    def fittable(self) -> dict[str, ParamSpec]:
        """Fittable parameters: attribute name -> ParamSpec."""


def init_alphas(owner: str, alpha_x: ArrayLike, alpha_y: ArrayLike | None):
    """Validated (alpha_x, alpha_y or None). Negative or non-finite roughness raises."""
    ax = as_param(owner, "alpha_x", alpha_x, lower=0.0)
    ay = None if alpha_y is None else as_param(owner, "alpha_y", alpha_y, lower=0.0)
    return ax, ay


def clamped_alphas(alpha_x: ArrayLike, alpha_y: ArrayLike | None) -> tuple[Array, Array]:
    """Roughness clamped to the model's floor ALPHA_MIN (gradient 0 below it)."""
    ax = jnp.maximum(alpha_x, ALPHA_MIN)
    ay = ax if alpha_y is None else jnp.maximum(alpha_y, ALPHA_MIN)
    return ax, ay


def alpha_specs(alpha_y: Array | None) -> dict[str, ParamSpec]:
    """alpha in (ALPHA_MIN, 1) through a sigmoid: beyond 1 a surface is as rough
    as these models describe meaningfully."""
    spec = ParamSpec(ALPHA_MIN, 1.0, "sigmoid")
    return {"alpha_x": spec} if alpha_y is None else {"alpha_x": spec, "alpha_y": spec}


def split(w: Float[Array, "*batch 3"]):
    """(x, y, z), each [*batch, 1]."""
    return w[..., 0:1], w[..., 1:2], w[..., 2:3]
