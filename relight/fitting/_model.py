"""The per-sample reflectance model the fitter solves for: parameter layout,
smooth transforms to the parameters' bounds, the forward model and the
robust residual.

Unconstrained vector u (all O(1), because Optimistix's Levenberg-Marquardt
damps with a plain identity):

    rho_d [3]  sigmoid -> (0, 1)          diffuse albedo per channel
    rho_s      sigmoid -> (0, 1)          specular albedo (Schlick F0 / Blinn-Phong lobe albedo)
    alpha_x    floor + (1 - floor) sigmoid  roughness (Blinn-Phong: s = 2 / alpha^2 - 2)
    alpha_y    as alpha_x                 anisotropic rung only
    phi        identity (radians)         anisotropy axis about the normal, anisotropic rung only
    n_a, n_b   the (a, b, 1) chart        normal = normalize(a, b, 1) in the surface's frame

Rungs without a parameter leave it out of u (static layout per rung).

One model, evaluated two ways. :func:`predict` is the reference: the one
OLAT forward model, ``stage.reflected_radiance``, of the rung's BRDF composed
from ``brdf``'s Modules (:func:`material`), in the [N, 3] layout and the
fitted frame. :func:`residual_and_jacobian` is the solver's fast path: the
same ``brdf`` kernels (``ggx_d_xyz``, ``ggx_g1_over_cos_xyz``, ``schlick``,
``blinn_phong_lobe``, ``phong_exponent``) on component-major observation
arrays ([3, N], so XLA vectorises over the lights), the specular lobe
evaluated once per light instead of per channel, and the Jacobian built from
its structure -- the diffuse columns in closed form, forward-mode tangents
only through the lobe and the normal -- several times cheaper than
``jax.jacfwd`` of :func:`predict` (``scripts/profile_fit_step.py``).
tests/relight/test_fit_model.py holds the fast path to :func:`predict` and
:func:`predict` to ``stage.reflected_radiance`` of the fitted
``LadderBRDF`` and to ``stage.simulate``, on every rung.
:func:`materialised_residual` hands that Jacobian to Optimistix through a
custom JVP, so each solver step evaluates the model once.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

import brdf
import stage
from brdf import phong_exponent, safe_normalize

from ..materials._maps import BLINN_PHONG, GGX, GGX_ANISO, LAMBERT


@dataclasses.dataclass(frozen=True)
class Layout:
    """The static parameter layout of one rung: which entries the unconstrained
    vector u of a sample holds (``names``, ``size``) and how they map to the
    physical parameters (the module docstring's table).

    Args:
        model: the rung, an index into ``relight.MODELS`` (``relight.materials.LAMBERT``,
            ``BLINN_PHONG``, ``GGX`` or ``GGX_ANISO``).
        normals: whether the shading normal is fitted (two entries, the (a, b, 1) chart).
        alpha_floor: the smallest roughness the fit allows, in (0, 1) (``relight.fitting.rig_alpha_floor``).
    """

    model: int
    normals: bool
    alpha_floor: float

    @property
    def names(self) -> tuple[str, ...]:
        n = ["rho_d.r", "rho_d.g", "rho_d.b"]
        if self.model >= BLINN_PHONG:
            n += ["rho_s", "alpha_x"]
        if self.model >= GGX_ANISO:
            n += ["alpha_y", "phi"]
        if self.normals:
            n += ["normal.a", "normal.b"]
        return tuple(n)

    @property
    def size(self) -> int:
        return len(self.names)


# Physical parameters of one sample: rho_d [3], rho_s [1], alpha [2], phi [],
# normal [3] (surface frame); a plain dict so that it is a pytree.
Params = dict


def sigmoid_inv(x):
    x = jnp.clip(x, 1e-4, 1 - 1e-4)
    return jnp.log(x) - jnp.log1p(-x)


def unpack(u, lay: Layout) -> Params:
    """Unconstrained u [size] -> physical parameters (defaults for absent ones)."""
    dt = u.dtype
    i = 3
    p = Params(rho_d=jax.nn.sigmoid(u[0:3]), rho_s=jnp.zeros(1, dt), alpha=jnp.full(2, 0.5, dt),
               phi=jnp.zeros((), dt), normal=jnp.asarray([0.0, 0.0, 1.0], dt))
    span = 1.0 - lay.alpha_floor
    if lay.model >= BLINN_PHONG:
        p["rho_s"] = jax.nn.sigmoid(u[i:i + 1])
        ax = lay.alpha_floor + span * jax.nn.sigmoid(u[i + 1:i + 2])
        p["alpha"] = jnp.concatenate([ax, ax])
        i += 2
    if lay.model >= GGX_ANISO:
        ay = lay.alpha_floor + span * jax.nn.sigmoid(u[i:i + 1])
        p["alpha"] = jnp.concatenate([p["alpha"][:1], ay])
        p["phi"] = u[i + 1]
        i += 2
    if lay.normals:
        p["normal"] = safe_normalize(jnp.concatenate([u[i:i + 2], jnp.ones(1, dt)]))
    return p


def pack(p: Params, lay: Layout):
    """Inverse of :func:`unpack` (``normal`` must have n_z > 0)."""
    span = 1.0 - lay.alpha_floor
    parts = [sigmoid_inv(p["rho_d"])]
    if lay.model >= BLINN_PHONG:
        parts += [sigmoid_inv(p["rho_s"]), sigmoid_inv((p["alpha"][:1] - lay.alpha_floor) / span)]
    if lay.model >= GGX_ANISO:
        parts += [sigmoid_inv((p["alpha"][1:2] - lay.alpha_floor) / span), jnp.reshape(p["phi"], (1,))]
    if lay.normals:
        n = p["normal"]
        nz = jnp.maximum(n[2:3], 0.05)
        parts += [n[0:2] / nz]
    return jnp.concatenate(parts)


def frame(normal, phi):
    """Rows (t, b, n) of the fitted frame in the surface's frame: n given, t the
    surface tangent projected off n, then rotated by phi about n."""
    t0 = jnp.asarray([1.0, 0.0, 0.0], normal.dtype)
    t = safe_normalize(t0 - normal[0] * normal)
    b = jnp.cross(normal, t)
    c, s = jnp.cos(phi), jnp.sin(phi)
    return jnp.stack([c * t + s * b, c * b - s * t, normal])


def _lobe(model: int, rho_s, alpha):
    """The specular lobe of a rung as a brdf Module (None for Lambert), for
    directions [N, 3]: rho_s [1] and alpha [2] of one sample become [1, 1]
    parameters. Blinn-Phong: ``brdf.BlinnPhong`` with no diffuse term and
    exponent ``brdf.phong_exponent(alpha_x)``; GGX: ``brdf.Microfacet`` with
    GGX (alpha_y only on the anisotropic rung), Schlick F0 = rho_s and
    separable Smith masking."""
    if model == LAMBERT:
        return None
    col = lambda x: jnp.reshape(x, (1, 1))  # noqa: E731
    ax = col(alpha[0])
    if model == BLINN_PHONG:
        return brdf.BlinnPhong(jnp.zeros((), ax.dtype), col(rho_s), phong_exponent(ax))
    ay = col(alpha[1]) if model >= GGX_ANISO else None
    return brdf.Microfacet(brdf.GGX(ax, ay), brdf.SchlickFresnel(col(rho_s)), "smith")


def material(p: Params, lay: Layout):
    """The rung's BRDF for one sample's parameters, composed from brdf's
    Modules (Lambert rho_d plus :func:`_lobe`); directions [N, 3] in the
    fitted frame give f_r [N, 3]. The same BRDF as :class:`LadderBRDF` with
    ``include_diffuse=True`` (what :meth:`Fit.material` returns), written
    separately so that the tests hold each to the other."""
    diffuse = brdf.Lambert(jnp.reshape(p["rho_d"], (1, 3)))
    lobe = _lobe(lay.model, p["rho_s"], p["alpha"])
    return diffuse if lobe is None else brdf.Sum(diffuse, lobe)


def specular(lay_model: int, rho_s, alpha, wi, wo):
    """Specular lobe [N, 1] of a rung in its local frame (no cosine; 0 below
    the horizon): :func:`_lobe` evaluated."""
    lobe = _lobe(lay_model, rho_s, alpha)
    if lobe is None:
        return jnp.zeros(wi.shape[:-1] + (1,), wi.dtype)
    return lobe(wi, wo)


# Smallest cosine of the view to the fitted normal (about 88.9 degrees).
_COS_O_MIN = 0.02


def fitted_directions(p: Params, wi, wo):
    """wi, wo [N, 3] from the surface's frame to the fitted frame (:func:`frame`),
    with the view kept just above the fitted normal's horizon (cos >= _COS_O_MIN).

    Every observation was seen by its camera, so the view cannot be below the
    fitted normal's horizon: keep it just above (a tilted normal at a grazing
    view would otherwise zero the whole prediction and its gradient, and the
    solver would stop there reporting success). Fitter geometry, not physics."""
    R = frame(p["normal"], p["phi"])
    return wi @ R.T, view_above_horizon(wo @ R.T)


def view_above_horizon(wo):
    """Unit views wo [..., 3] (local frame) with cos kept >= _COS_O_MIN: the
    fitter's clamp of :func:`fitted_directions`, shared with the subsurface fit."""
    return safe_normalize(jnp.concatenate([wo[..., :2], jnp.maximum(wo[..., 2:3], _COS_O_MIN)], axis=-1))


def predict(p: Params, lay: Layout, wi, wo, irr):
    """Radiance [N, C] of one sample: wi [N, 3], wo [N, 3] in the surface's
    frame, irradiance at normal incidence irr [N, C]. The one OLAT model,
    ``stage.reflected_radiance`` of the rung's :func:`material`, in the
    fitted frame (:func:`fitted_directions`)."""
    wi_f, wo_f = fitted_directions(p, jnp.asarray(wi), jnp.asarray(wo))
    return stage.reflected_radiance(material(p, lay), wi_f, wo_f, jnp.asarray(irr))


def _specular_cm(model: int, rho_s, alpha, wi, wo):
    """Specular lobe [N] of a rung, component-major wi, wo [3, N] in the fitted
    frame with wo above the horizon; 0 for wi below it (GGX) or unmasked
    (Blinn-Phong: the caller masks). The lobes of :func:`_lobe`, from brdf's
    elementwise kernels on the component rows: GGX D (Walter et al. 2007,
    eq. 33), separable Smith G1 / cos (eq. 34), Schlick 1994 Fresnel;
    Blinn-Phong's normalised lobe with ``brdf.phong_exponent``."""
    h = wi + wo
    inv_h = jax.lax.rsqrt(jnp.maximum(jnp.sum(h * h, axis=0), 1e-30))
    if model == BLINN_PHONG:
        return brdf.blinn_phong_lobe(h[2] * inv_h, rho_s[0], phong_exponent(alpha[0]))
    ax, ay = alpha[0], (alpha[1] if model >= GGX_ANISO else None)
    m = h * inv_h[None]
    d = brdf.ggx_d_xyz(m[0], m[1], m[2], ax, ay)
    fresnel = brdf.schlick(jnp.sum(wi * m, axis=0), rho_s[0])
    g = brdf.smith_g2_separable_over_cos(brdf.ggx_g1_over_cos_xyz(wi[0], wi[1], wi[2], ax, ay),
                                         brdf.ggx_g1_over_cos_xyz(wo[0], wo[1], wo[2], ax, ay))
    return d * fresnel * g


def _shading_cm(q, lay: Layout, wi, wo):
    """(specular lobe [N], cos_i [N]) of the non-diffuse parameters q = u[3:]
    for component-major wi, wo [3, N] in the surface's frame (:func:`predict`'s
    frame, view clamp and masks)."""
    p = unpack(jnp.concatenate([jnp.zeros(3, q.dtype), q]), lay)
    R = frame(p["normal"], p["phi"])
    # Explicit multiply-adds: a [3, 3] x [3, N] dot per sample vectorises badly under vmap.
    rot = lambda w: jnp.stack([R[r, 0] * w[0] + R[r, 1] * w[1] + R[r, 2] * w[2] for r in range(3)])  # noqa: E731
    wi_f, wo_f = rot(wi), rot(wo)
    wo_f = jnp.stack([wo_f[0], wo_f[1], jnp.maximum(wo_f[2], _COS_O_MIN)])
    wo_f = wo_f * jax.lax.rsqrt(jnp.sum(wo_f * wo_f, axis=0))[None]
    lit = wi_f[2] > 0
    cos_i = jnp.where(lit, wi_f[2], 0.0)
    if lay.model == LAMBERT:
        return jnp.zeros_like(cos_i), cos_i
    # The kernels are finite (with finite tangents) on unlit lights; the mask zeroes them there.
    lobe = _specular_cm(lay.model, p["rho_s"], p["alpha"], wi_f, wo_f)
    return jnp.where(lit, lobe, 0.0), cos_i


def residual_and_jacobian(u, obs, sw, wi, wo, irr, lay: Layout, c):
    """The solver's residual and its Jacobian for one sample: the fitter's fast path.

    r = robust(sw (pred - obs), c) with pred the model of :func:`predict`
    (the same ``brdf`` kernels, component-major so XLA vectorises over the
    observations) and robust the square-rooted Cauchy residual (:func:`robust`).
    pred_c = (rho_c / pi + lobe) cos_i irr_c, so the diffuse columns of J are
    in closed form and only the lobe and cos_i carry forward-mode tangents
    (one batched JVP over u[3:]): several times cheaper than ``jax.jacfwd``.

    Args:
        u: [size] the sample's unconstrained parameters (``lay.names``).
        obs: [3, N] observed radiance, component-major (channel, observation).
        sw: [3, N] square root of each observation's weight (0: padding).
        wi, wo: [3, N] unit directions to the light and the camera in the
            sample's surface frame (rows x, y, z; z = the surface normal).
        irr: [3, N] irradiance at normal incidence.
        lay: the rung's :class:`Layout`.
        c: the Cauchy scale in radiance units, or None for plain least squares.

    Returns:
        (r [3N], J [3N, size] = dr/du, pred [3, N] the raw prediction).

    References:
        Walter et al. 2007, "Microfacet models for refraction through rough
        surfaces", eqs. 33-34 (GGX D and separable Smith G1); Schlick 1994
        (Fresnel); Triggs et al. 2000, "Bundle adjustment -- a modern
        synthesis" (the square-rooted robust residual).
    """
    rho = jax.nn.sigmoid(u[:3])
    q = u[3:]
    k = q.shape[0]
    shade = lambda v: _shading_cm(v, lay, wi, wo)  # noqa: E731
    if k:
        basis = jnp.eye(k, dtype=u.dtype)
        (lobe, cos_i), (d_lobe, d_cos) = jax.vmap(lambda e: jax.jvp(shade, (q,), (e,)), out_axes=(None, 0))(basis)
    else:
        lobe, cos_i = shade(q)
    base = rho[:, None] / jnp.pi + lobe[None]  # [3, N]
    pred = base * cos_i[None] * irr
    r, dr = jax.jvp(lambda x: robust(x, c), (sw * (pred - obs),), (jnp.ones_like(obs),))
    g = dr * sw * irr  # d r / d pred, per observation [3, N]
    # Diffuse columns: channel c's rows depend on u_c only.
    d_rho = (rho * (1.0 - rho) / jnp.pi)[:, None, None] * jnp.eye(3, dtype=u.dtype)[:, :, None]
    j_rho = d_rho * (g * cos_i[None])[None]
    cols = [j_rho]
    if k:
        cols.append(g[None] * (d_lobe[:, None] * cos_i[None, None] + base[None] * d_cos[:, None]))
    Jt = jnp.concatenate(cols, axis=0).reshape(3 + k, -1)
    return r.reshape(-1), Jt.T, pred


def materialised(rj):
    """u -> r for ``rj(u) -> (r [m], J [m, k], ...)`` (a residual and its
    structured Jacobian), whose JVP is the materialised Jacobian times the
    tangent: Optimistix linearises it once per step at the cost of one model
    evaluation, and its linear solves multiply by J (and J^T) instead of
    re-tracing the model. Shared by the OLAT and the pattern residuals."""

    @jax.custom_jvp
    def residual(u):
        return rj(u)[0]

    @residual.defjvp
    def _jvp(primals, tangents):
        r, J = rj(primals[0])[:2]
        return r, tangents[0] @ J.T

    return residual


def materialised_residual(obs, sw, wi, wo, irr, lay: Layout, c):
    """u -> robust residual [3N] (:func:`residual_and_jacobian`) with the
    materialised Jacobian as its JVP (:func:`materialised`)."""
    return materialised(lambda u: residual_and_jacobian(u, obs, sw, wi, wo, irr, lay, c))


def cauchy_scale(y):
    """sqrt(log1p(y) / y) for y = (r / c)^2 >= 0, smooth at 0 (limit 1)."""
    small = y < 1e-6
    ys = jnp.where(small, 1.0, y)
    return jnp.where(small, 1.0 - 0.25 * y, jnp.sqrt(jnp.log1p(ys) / ys))


def robust(r, c):
    """Residuals whose sum of squares is the Cauchy loss c^2 sum log(1 + (r/c)^2)
    (Triggs et al. 2000's square-rooted robust residual); c = inf gives plain L2."""
    if c is None:
        return r
    return r * cauchy_scale((r / c) ** 2)


def physical_vector(p: Params, lay: Layout):
    """The reported parameters of a rung as one vector (for uncertainties):
    rho_d [3], then rho_s, alpha_x (>= Blinn-Phong), alpha_y, phi (aniso), and the
    normal's tilt components n_x, n_y (radians, small-angle) when fitted."""
    parts = [p["rho_d"]]
    if lay.model >= BLINN_PHONG:
        parts += [p["rho_s"], p["alpha"][:1]]
    if lay.model >= GGX_ANISO:
        parts += [p["alpha"][1:2], jnp.reshape(p["phi"], (1,))]
    if lay.normals:
        parts += [p["normal"][0:2]]
    return jnp.concatenate(parts)


__all__ = ["Layout", "Params", "unpack", "pack", "material", "fitted_directions", "predict", "residual_and_jacobian",
           "materialised", "materialised_residual", "robust", "physical_vector", "frame", "view_above_horizon",
           "LAMBERT", "BLINN_PHONG", "GGX", "GGX_ANISO"]
