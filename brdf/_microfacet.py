"""The composable microfacet reflection model and the foundation model
``lambert_ggx`` (a Lambert base plus a GGX specular lobe)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._base import AbstractBRDF, ParamSpec, check_directions, check_module_rank, cos_theta
from ._distribution import AbstractMicrofacetDistribution
from ._fresnel import AbstractFresnel, SchlickFresnel
from ._ggx import GGX
from ._lambert import Lambert
from ._safe import dot, lift_grazing, safe_div, safe_normalize
from ._sum import Sum

MASKINGS = ("smith", "smith_height_correlated", "v_groove")


def smith_g2_separable_over_cos(
    g1_over_cos_i: Float[ArrayLike, "*#shape"], g1_over_cos_o: Float[ArrayLike, "*#shape"]
) -> Float[Array, "*shape"]:
    """Separable Smith masking-shadowing over the microfacet BRDF's 4 cos_i cos_o: G1(wi) G1(wo) / (4 cos_i cos_o).

    Built from the distribution's G1 / cos values (``ggx_g1_over_cos``, ``beckmann_g1_over_cos``), so finite at
    grazing angles. Elementwise.

    Args:
        g1_over_cos_i: G1(wi) / cos(theta_i).
        g1_over_cos_o: G1(wo) / cos(theta_o).

    Returns:
        G2 / (4 cos_i cos_o) (unitless), the broadcast shape.

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eq. 23.
    """
    return 0.25 * jnp.asarray(g1_over_cos_i) * jnp.asarray(g1_over_cos_o)


def smith_g2_height_correlated_over_cos(
    cos_theta_i: Float[ArrayLike, "*#shape"],
    cos_theta_o: Float[ArrayLike, "*#shape"],
    lambda_cos_i: Float[ArrayLike, "*#shape"],
    lambda_cos_o: Float[ArrayLike, "*#shape"],
) -> Float[Array, "*shape"]:
    """Height-correlated Smith masking-shadowing over 4 cos_i cos_o, G2 = 1 / (1 + Lambda(wi) + Lambda(wo)).

    From the distribution's cos(theta) Lambda values (``ggx_lambda_cos``, ``beckmann_lambda_cos``):
    G2 / (4 cos_i cos_o) = 1 / (4 (cos_i cos_o + cos_o lc_i + cos_i lc_o)), finite at grazing angles. Elementwise.

    Args:
        cos_theta_i, cos_theta_o: cosines of the incident and outgoing directions.
        lambda_cos_i, lambda_cos_o: cos(theta) Lambda(w) of each.

    Returns:
        G2 / (4 cos_i cos_o) (unitless), the broadcast shape; 0 (gradient 0) where the denominator is 0.

    References:
        Heitz 2014, "Understanding the masking-shadowing function in microfacet-based BRDFs", JCGT 3(2), eq. 99.
    """
    den = cos_theta_i * cos_theta_o + cos_theta_o * lambda_cos_i + cos_theta_i * lambda_cos_o
    return safe_div(0.25, den)


def v_groove_g2_over_cos(
    cos_theta_i: Float[ArrayLike, "*#shape"],
    cos_theta_o: Float[ArrayLike, "*#shape"],
    cos_theta_m: Float[ArrayLike, "*#shape"],
    wo_dot_wm: Float[ArrayLike, "*#shape"],
) -> Float[Array, "*shape"]:
    """V-groove attenuation G = min(1, 2 zm zo / (wo.wm), 2 zm zi / (wo.wm)) over 4 cos_i cos_o.

    Evaluated without dividing by a lone cosine, so finite at grazing angles. Elementwise; meaningful where both
    directions are above the horizon.

    Args:
        cos_theta_i, cos_theta_o: cosines of the incident and outgoing directions (zi, zo).
        cos_theta_m: cosine of the microfacet normal (zm).
        wo_dot_wm: wo . wm.

    Returns:
        G / (4 cos_i cos_o) (unitless), the broadcast shape.

    References:
        Cook & Torrance 1982, "A reflectance model for computer graphics" (after Torrance & Sparrow 1967).
    """
    lo = jnp.minimum(cos_theta_i, cos_theta_o)
    hi = jnp.maximum(cos_theta_i, cos_theta_o)
    # G = 2 zm lo / h when that is < 1; then G / (4 zi zo) = zm / (2 h hi).
    shadowed = 2.0 * cos_theta_m * lo < wo_dot_wm
    return jnp.where(shadowed, safe_div(cos_theta_m, 2.0 * wo_dot_wm * hi), safe_div(1.0, 4.0 * lo * hi))


def masking_over_cos(
    distribution: AbstractMicrofacetDistribution,
    masking: str,
    wi: Float[Array, "*batch 3"],
    wo: Float[Array, "*batch 3"],
    wm: Float[Array, "*batch 3"],
) -> Float[Array, "*batch C"]:
    """G(wi, wo, wm) / (4 cos_i cos_o), evaluated without dividing by the cosines
    so that it stays finite at grazing angles (cos = 1e-7) for every masking:

    - ``"smith"``: separable G1(wi) G1(wo) (Walter et al. 2007, eq. 23).
    - ``"smith_height_correlated"``: 1 / (1 + Lambda(wi) + Lambda(wo)) (Heitz 2014, eq. 99).
    - ``"v_groove"``: min(1, 2 zm zo / (wo.wm), 2 zm zi / (wo.wm)) (Cook & Torrance
      1982, after Torrance & Sparrow 1967).

    Only meaningful where both directions are above the horizon (the caller masks).
    """
    zi, zo = cos_theta(wi), cos_theta(wo)
    if masking == "smith":
        return smith_g2_separable_over_cos(distribution.g1_over_cos(wi), distribution.g1_over_cos(wo))
    if masking == "smith_height_correlated":
        return smith_g2_height_correlated_over_cos(zi, zo, distribution.lambda_cos(wi), distribution.lambda_cos(wo))
    if masking == "v_groove":
        return v_groove_g2_over_cos(zi, zo, cos_theta(wm), dot(wo, wm))
    raise ValueError(f"masking must be one of {MASKINGS}, got {masking!r}")


class Microfacet(AbstractBRDF):
    """Microfacet reflection f_r = D(wm) F(wi.wm) G(wi, wo) / (4 cos_i cos_o)
    (Cook & Torrance 1982; Walter et al. 2007, eq. 20), wm = normalize(wi + wo).

    ``distribution``: GGX or Beckmann; ``fresnel``: SchlickFresnel, ConductorFresnel
    or DielectricFresnel; ``masking``: ``"smith"`` (separable G1 G1),
    ``"smith_height_correlated"`` or ``"v_groove"``. Reciprocal. With a Fresnel
    <= 1 its directional albedo is <= 1 (Smith masking loses the energy of
    multiple scattering; V-groove does not bound it exactly at high roughness).
    """

    distribution: AbstractMicrofacetDistribution
    fresnel: AbstractFresnel
    masking: str = eqx.field(static=True)

    def __init__(self, distribution: AbstractMicrofacetDistribution, fresnel: AbstractFresnel,
                 masking: str = "smith"):
        if not isinstance(distribution, AbstractMicrofacetDistribution):
            raise ValueError(
                f"Microfacet: distribution must be a GGX or Beckmann module, got {type(distribution).__name__}"
            )
        if not isinstance(fresnel, AbstractFresnel):
            raise ValueError(f"Microfacet: fresnel must be a Fresnel module, got {type(fresnel).__name__}")
        if masking not in MASKINGS:
            raise ValueError(f"Microfacet: masking must be one of {MASKINGS}, got {masking!r}")
        self.distribution = distribution
        self.fresnel = fresnel
        self.masking = masking

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """f_r in 1/sr; 0 where either direction is at or below the horizon."""
        wi, wo = check_directions("Microfacet", wi, wo)
        check_module_rank(self, wi.ndim)
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        # cosines raised to the grazing floor: V-groove's G / (cos_i cos_o) and the
        # half vector's 1 / |wi + wo| stay bounded (see brdf._safe.GRAZING_ULPS)
        wi, wo = lift_grazing(wi), lift_grazing(wo)
        wm = safe_normalize(wi + wo)
        cos_d = dot(wi, wm)
        f = self.distribution.D(wm) * self.fresnel(cos_d) * masking_over_cos(
            self.distribution, self.masking, wi, wo, wm
        )
        return jnp.where(active, f, 0.0)

    def sample(self, wo: Float[Array, "*batch 3"], u: Float[Array, "*batch 2"]):
        """(wi, pdf): wi reflected about a microfacet normal from
        ``distribution.sample_wm``; pdf in 1/sr over wi is pdf_wm / (4 wo.wm)
        (Walter et al. 2007, eq. 14). pdf is 0 (and wi may point down) where the
        sample leaves the upper hemisphere."""
        wm = self.distribution.sample_wm(wo, u)
        wo_wm = dot(wo, wm)
        wi = 2.0 * wo_wm * wm - wo
        return wi, self.pdf(wo, wi)

    def pdf(self, wo: Float[Array, "*batch 3"], wi: Float[Array, "*batch 3"]) -> Float[Array, "*batch C"]:
        """Density of ``sample`` over wi, in 1/sr; 0 when either direction is below the horizon."""
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        wm = safe_normalize(wi + wo)
        wo_wm = dot(wo, wm)
        p = safe_div(self.distribution.pdf_wm(wo, wm), 4.0 * wo_wm)
        return jnp.where(active, p, 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """The distribution's and the Fresnel term's parameters, prefixed
        ``distribution.`` and ``fresnel.``."""
        out = {f"distribution.{k}": v for k, v in self.distribution.fittable().items()}
        out.update({f"fresnel.{k}": v for k, v in self.fresnel.fittable().items()})
        return out


def lambert_ggx(rho_d: ArrayLike, f0: ArrayLike, alpha: ArrayLike) -> Sum:
    """The foundation model f_r = rho_d / pi + D_GGX F_Schlick(f0) G_smith / (4 cos_i cos_o).

    Fittable names: ``terms.0.albedo``, ``terms.1.fresnel.f0``, ``terms.1.distribution.alpha_x``.

    Args:
        rho_d: diffuse albedo [*batch, 3].
        f0: specular albedo [*batch, 1] (Schlick reflectance at normal incidence).
        alpha: isotropic GGX roughness [*batch, 1].

    Returns:
        A ``Sum`` of ``Lambert`` and a GGX ``Microfacet`` with Schlick Fresnel and separable Smith masking.

    References:
        Kang et al. 2018, "Efficient reflectance capture using an autoencoder" (the form it fits);
        Walter et al. 2007, "Microfacet models for refraction through rough surfaces", eq. 20 and 33-34.
    """
    return Sum(Lambert(rho_d), Microfacet(GGX(alpha), SchlickFresnel(f0), "smith"))
