"""The one OLAT forward model: the radiance a camera records from a surface
sample under one light, written once and used by ``stage.simulate``, by the
fitter's model (``relight.fitting``) and by the directional relighting
methods (``relight.render``: "rig" and "dense").

Surface reflection of a point or distant light (pbrt-v4 eq. 4.14 with a delta
light):

    L_r(p, wo) = f_r(wi, wo) max(cos theta_i, 0) E_l(p) V_l(p)

with E_l the irradiance at normal incidence (``incident_light``: the
inverse-square law for near-field lights) and V_l the visibility.

Subsurface (Jensen et al. 2001's diffusion BSSRDF, eq. 5, integrated over the
surface by a ``skin_bssrdf.DiffusionOperator`` with weights w_oj):

    L_ss(x_o, wo) = F_t(eta, cos_o) / pi * sum_j w_oj F_t(eta, cos_i,j) cos_i,j E_l,j V_l,j

split into ``subsurface_irradiance`` (what enters at each x_j) and
``subsurface_exitance`` (what leaves x_o toward the camera), with the operator
applied in between. Everything here is pure JAX: differentiable in the
material, the shading frame, the light positions and intensities and the
camera.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

import brdf
from brdf import safe_normalize


def _traced(*trees) -> bool:
    """True when any array leaf is a JAX tracer (under jax.grad, jvp, jit or vmap)."""
    return any(isinstance(x, jax.core.Tracer) for t in trees for x in jax.tree_util.tree_leaves(t))


def widest_float(*trees):
    """The widest floating dtype among the array leaves of ``trees`` (float32 when there is none), as JAX
    holds it (float64 only under ``jax_enable_x64``): what a computation over them returns, so float64 inputs
    are never narrowed silently."""
    dts = [jnp.dtype(x.dtype) for t in trees for x in jax.tree_util.tree_leaves(t)
           if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating)]
    return jax.dtypes.canonicalize_dtype(max(dts, key=lambda d: d.itemsize, default=jnp.dtype(jnp.float32)))


def as_float(tree, dtype):
    """``tree`` with every floating array leaf in ``dtype`` (leaves already in it, and other leaves, as they are)."""
    def cast(x):
        if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating) and jnp.dtype(x.dtype) != dtype:
            return x.astype(dtype)
        return x

    return jax.tree_util.tree_map(cast, tree)


def incident_light(
    position: Float[Array, "light 3"],
    intensity: Float[Array, "light channel"],
    near_field: bool,
    points: Float[ArrayLike, "*batch 3"],
) -> tuple[Float[Array, "light *batch 3"], Float[Array, "light *batch channel"]]:
    """World direction toward each light and the irradiance at normal incidence it delivers at each point.

    Near field: an isotropic point source of radiant intensity I [W sr^-1] at ``position`` (mm) gives
    E = I / |x - p|^2 (inverse-square law). Distant: ``position`` is along the direction and ``intensity`` is the
    irradiance E itself, the same at every point.

    Args:
        position: light positions (mm) or directions, [L, 3].
        intensity: radiant intensity (near field) or irradiance (distant), [L, C].
        near_field: point sources (True) or distant lights (False).
        points: the shaded points (mm), [*batch, 3].

    Returns:
        (unit directions toward the lights [L, *batch, 3], irradiance at normal incidence [L, *batch, C]).
    """
    points = jnp.asarray(points)
    extra = (1,) * (points.ndim - 1)
    pos = position.reshape((-1,) + extra + (3,))
    inten = intensity.reshape((-1,) + extra + (intensity.shape[-1],))
    if near_field:
        delta = pos - points[None]
        d2 = jnp.sum(delta * delta, axis=-1, keepdims=True)
        return safe_normalize(delta), inten / d2
    n = position.shape[0]
    wi = jnp.broadcast_to(safe_normalize(pos), (n,) + points.shape)
    irr = jnp.broadcast_to(inten, (n,) + points.shape[:-1] + (inten.shape[-1],))
    return wi, irr


def to_local(
    w: Float[ArrayLike, "*batch sample 3"],
    tangent: Float[Array, "sample 3"],
    bitangent: Float[Array, "sample 3"],
    normal: Float[Array, "sample 3"],
) -> Float[Array, "*batch sample 3"]:
    """World directions in each sample's shading frame (z = normal): the components along (t, b, n).

    Args:
        w: world directions [*batch, P, 3]; leading axes broadcast.
        tangent, bitangent, normal: each sample's orthonormal frame, [P, 3].

    Returns:
        Local directions [*batch, P, 3].
    """
    w = jnp.asarray(w)
    lead = (1,) * (w.ndim - 2)
    t, b, n = (x.reshape(lead + x.shape) for x in (tangent, bitangent, normal))
    return jnp.stack([jnp.sum(w * t, -1), jnp.sum(w * b, -1), jnp.sum(w * n, -1)], axis=-1)


def reflected_radiance(
    material,
    wi: Float[Array, "*#batch 3"],
    wo: Float[Array, "*#batch 3"],
    irradiance: Float[Array, "*#batch channel"],
    visible: Bool[Array, " *#batch"] | None = None,
) -> Float[Array, "*batch channel"]:
    """Reflected radiance L_r = f_r(wi, wo) max(cos theta_i, 0) E V for one light per element.

    Args:
        material: a brdf Module (its parameters broadcast against the batch).
        wi, wo: incident and outgoing unit directions in the local frame, [*batch, 3].
        irradiance: irradiance at normal incidence, [*batch, C].
        visible: the light's visibility, [*batch] (None: visible).

    Returns:
        Radiance [*batch, C], in the irradiance's units per sr.

    References:
        pbrt-v4, eq. 4.14 (a delta light).
    """
    f = material(wi, wo)
    out = f * jnp.maximum(wi[..., 2:3], 0.0) * irradiance
    if visible is not None:
        out = jnp.where(visible[..., None], out, 0.0)
    return out


@eqx.filter_jit
def reflected_radiance_lights(material, wi, wo, irradiance, visible=None):
    """``reflected_radiance`` over a leading light axis, one light at a time (the temporaries are one light's).

    Args:
        material: a brdf Module.
        wi: incident directions [L, P, 3] in the local frame.
        wo: outgoing directions [P, 3] in the local frame.
        irradiance: irradiance at normal incidence [L, P, C].
        visible: visibility [L, P] (None: visible).

    Returns:
        Radiance [L, P, C].

    References:
        pbrt-v4, eq. 4.14 (a delta light).
    """
    if visible is None:
        return jax.vmap(lambda w, e: reflected_radiance(material, w, wo, e))(wi, irradiance)
    return jax.vmap(lambda w, e, v: reflected_radiance(material, w, wo, e, v))(wi, irradiance, visible)


def subsurface_irradiance(
    wi: Float[Array, "*#batch 3"],
    irradiance: Float[Array, "*#batch channel"],
    eta,
    lit: Bool[Array, " *#batch"] | None = None,
) -> Float[Array, "*batch channel"]:
    """Irradiance transmitted into the medium, F_t(eta, cos_i) max(cos_i, 0) E V.

    Args:
        wi: incident unit directions in the local frame, [*batch, 3].
        irradiance: irradiance at normal incidence, [*batch, C].
        eta: relative refractive index of the medium.
        lit: the light's visibility, [*batch] (None: visible).

    Returns:
        Transmitted irradiance [*batch, C].

    References:
        Jensen et al. 2001, "A practical model for subsurface light transport", eq. 5 (its inner factor).
    """
    cos_i = jnp.maximum(wi[..., 2:3], 0.0)
    e = brdf.fresnel_transmittance(cos_i, eta) * cos_i * irradiance
    if lit is not None:
        e = jnp.where(lit[..., None], e, 0.0)
    return e


def subsurface_exitance(
    exitance: Float[Array, "*#batch channel"],
    wo: Float[Array, "*#batch 3"],
    eta,
    seen: Bool[Array, " *#batch"] | None = None,
) -> Float[Array, "*batch channel"]:
    """Radiance leaving toward wo from the diffused exitance M: F_t(eta, cos_o) / pi * M.

    Args:
        exitance: the diffused exitance M = operator(E_t), [*batch, C].
        wo: outgoing unit directions in the local frame, [*batch, 3].
        eta: relative refractive index of the medium.
        seen: the sample's visibility from the camera, [*batch] (None: seen).

    Returns:
        Radiance [*batch, C].

    References:
        Jensen et al. 2001, "A practical model for subsurface light transport", eq. 5 (its outer factor).
    """
    out = brdf.fresnel_transmittance(jnp.maximum(wo[..., 2:3], 0.0), eta) / jnp.pi * exitance
    if seen is not None:
        out = jnp.where(seen[..., None], out, 0.0)
    return out
