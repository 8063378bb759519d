"""Sums of reflectance models (a diffuse base plus specular lobes)."""

from __future__ import annotations

from jaxtyping import Array, Float

from ._base import AbstractBRDF, ParamSpec, check_directions


class Sum(AbstractBRDF):
    """f_r = sum of the terms' f_r. Reciprocal when every term is; conserves
    energy when the terms' albedos add to <= 1 (not checked)."""

    terms: tuple[AbstractBRDF, ...]

    def __init__(self, *terms: AbstractBRDF):
        if not terms:
            raise ValueError("Sum needs at least one term")
        for i, t in enumerate(terms):
            if not isinstance(t, AbstractBRDF):
                raise ValueError(f"Sum: term {i} must be a BRDF module, got {type(t).__name__}")
        self.terms = tuple(terms)

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Sum of the terms, in 1/sr (channels broadcast: [*, 3] + [*, 1] -> [*, 3])."""
        wi, wo = check_directions("Sum", wi, wo)
        out = self.terms[0](wi, wo)
        for t in self.terms[1:]:
            out = out + t(wi, wo)
        return out

    def fittable(self) -> dict[str, ParamSpec]:
        """Each term's parameters, prefixed ``terms.<index>.``."""
        return {f"terms.{i}.{k}": v for i, t in enumerate(self.terms) for k, v in t.fittable().items()}
