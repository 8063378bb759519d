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
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

import brdf
from brdf import safe_normalize, safe_pow

from ._maps import BLINN_PHONG, GGX, GGX_ANISO, LAMBERT, phong_exponent


@dataclasses.dataclass(frozen=True)
class Layout:
    """Static parameter layout of one rung: ``model`` (index into MODELS),
    whether the normal is fitted, and the roughness floor of the fit."""

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


def specular(lay_model: int, rho_s, alpha, wi, wo):
    """Specular lobe [N, 1] of a rung in its local frame (no cosine)."""
    if lay_model == LAMBERT:
        return jnp.zeros(wi.shape[:-1] + (1,), wi.dtype)
    ax, ay = alpha[0:1], alpha[1:2]
    if lay_model == BLINN_PHONG:
        s = phong_exponent(ax)[None]
        cos_h = jnp.maximum(safe_normalize(wi + wo)[..., 2:3], 0.0)
        lobe = rho_s[None] * (s + 8.0) / (8.0 * jnp.pi) * safe_pow(cos_h, s)
        return jnp.where((wi[..., 2:3] > 0) & (wo[..., 2:3] > 0), lobe, 0.0)
    if lay_model < GGX_ANISO:
        ay = ax
    m = brdf.Microfacet(brdf.GGX(ax[None], ay[None]), brdf.SchlickFresnel(rho_s[None]), "smith")
    return m(wi, wo)


# Smallest cosine of the view to the fitted normal (about 88.9 degrees).
_COS_O_MIN = 0.02


def predict(p: Params, lay: Layout, wi, wo, irr):
    """Radiance [N, C] of one sample: wi [N, 3], wo [N, 3] in the surface's
    frame, irradiance at normal incidence irr [N, C]."""
    R = frame(p["normal"], p["phi"])
    wi_f, wo_f = wi @ R.T, wo @ R.T
    # Every observation was seen by its camera, so the view cannot be below the
    # fitted normal's horizon: keep it just above (a tilted normal at a grazing
    # view would otherwise zero the whole prediction and its gradient, and the
    # solver would stop there reporting success).
    wo_f = safe_normalize(jnp.concatenate([wo_f[..., :2], jnp.maximum(wo_f[..., 2:3], _COS_O_MIN)], axis=-1))
    cos_i = jnp.maximum(wi_f[..., 2:3], 0.0)
    lit = wi_f[..., 2:3] > 0
    f = jnp.where(lit, p["rho_d"] / jnp.pi, 0.0) + specular(lay.model, p["rho_s"], p["alpha"], wi_f, wo_f)
    return f * cos_i * irr


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


__all__ = ["Layout", "Params", "unpack", "pack", "predict", "robust", "physical_vector", "frame", "LAMBERT",
           "BLINN_PHONG", "GGX", "GGX_ANISO"]
