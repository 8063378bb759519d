"""Sums of Gaussians (d'Eon, Luebke & Enderton 2007, "Efficient Rendering of
Human Skin", EGSR; GPU Gems 3 ch. 14): the published six-Gaussian fit of a
three-layer skin profile, and fitting a sum of Gaussians to any profile."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from brdf import widest_float

from ._common import AbstractProfile, align, as_float, check, radius_arg
from ._radius import energy_radius

# d'Eon et al. 2007 (Table 1 / GPU Gems 3 Figure 14-13): variances in mm^2 and
# RGB weights of the six Gaussians fitted to the three-layer skin model of Donner &
# Jensen 2005. Each channel's weights sum to 1: the total (albedo) is applied separately.
DEON2007_VARIANCES = (0.0064, 0.0484, 0.187, 0.567, 1.99, 7.41)
DEON2007_WEIGHTS = (
    (0.233, 0.455, 0.649),
    (0.100, 0.336, 0.344),
    (0.118, 0.198, 0.0),
    (0.113, 0.007, 0.007),
    (0.358, 0.004, 0.0),
    (0.078, 0.0, 0.0),
)


class SumOfGaussians(AbstractProfile):
    """R(r) = sum_k w_k G(v_k, r), G(v, r) = e^{-r^2/(2v)} / (2 pi v), in 1/mm^2
    (d'Eon et al. 2007, eq. 2). Each G integrates to 1 over the plane, so
    ``total()`` = sum_k w_k.

    ``weights`` [..., K, C] (>= 0, dimensionless) and ``variances`` [K] (> 0, mm^2),
    shared by all channels (one blur per Gaussian in texture space).
    """

    weights: Float[Array, "*pbatch gaussian channel"]
    variances: Float[Array, " gaussian"]

    def __init__(self, weights: ArrayLike, variances: ArrayLike):
        check("SumOfGaussians", "weights", weights, lo=0.0)
        check("SumOfGaussians", "variances (mm^2)", variances, lo=0.0, lo_open=True)
        weights, variances = as_float(weights), as_float(variances)
        if variances.ndim != 1:
            raise ValueError(f"SumOfGaussians: variances must have shape [K], got {variances.shape}")
        if weights.ndim < 2 or weights.shape[-2] != variances.shape[0]:
            raise ValueError(
                f"SumOfGaussians: weights must have shape [..., K={variances.shape[0]}, C], got {weights.shape}"
            )
        dtype = widest_float(weights, variances)
        self.weights, self.variances = weights.astype(dtype), variances.astype(dtype)

    @classmethod
    def skin_deon2007(cls, albedo: ArrayLike = 1.0) -> SumOfGaussians:
        """d'Eon et al. 2007's six-Gaussian RGB fit of the three-layer skin profile,
        with total diffuse reflectance ``albedo`` per channel (shape [..., 3] or scalar)."""
        check("SumOfGaussians.skin_deon2007", "albedo", albedo, lo=0.0, hi=1.0)
        a = as_float(albedo)
        w = jnp.asarray(DEON2007_WEIGHTS, a.dtype)
        a = jnp.broadcast_to(a, a.shape[:-1] + (3,)) if a.ndim else jnp.broadcast_to(a, (3,))
        w, a = align(w, a[..., None, :])
        return cls(w * a, jnp.asarray(DEON2007_VARIANCES, a.dtype))

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.weights.shape[:-2]

    def radial(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """sum_k w_k e^{-r^2/(2 v_k)}/(2 pi v_k) in 1/mm^2; r in mm, [...] -> [..., C]."""
        r = radius_arg("SumOfGaussians.radial", r, self.weights.dtype)
        return _radial(r, self.weights, self.variances)

    def total(self) -> Float[Array, "*pbatch channel"]:
        """sum_k w_k."""
        return jnp.sum(self.weights, axis=-2)

    def cumulative(self, r: Float[ArrayLike, "*batch"]) -> Float[Array, "*batch channel"]:
        """sum_k w_k (1 - e^{-r^2/(2 v_k)})."""
        r = radius_arg("SumOfGaussians.cumulative", r, self.weights.dtype)
        return _cumulative(r, self.weights, self.variances)


@jax.jit
def _radial(r, w, v):
    if w.ndim == 2:
        # one set of weights [G, C]: G exponentials per radius, then a matrix product
        # (not G x C exponentials), the hot path of the diffusion operators
        r, v = align(r, v)  # r [..., 1] with v [G] -> [..., G]
        g = jnp.exp(-r * r / (2 * v)) / (2 * jnp.pi * v)
        return jnp.matmul(g, w, precision=jax.lax.Precision.HIGHEST)
    r = r[..., None, :]  # [..., 1, 1]: gaussian and channel axes
    v = v[:, None]
    r, w, v = align(r, w, v)
    return jnp.sum(w * jnp.exp(-r * r / (2 * v)) / (2 * jnp.pi * v), axis=-2)


@jax.jit
def _cumulative(r, w, v):
    r = r[..., None, :]
    v = v[:, None]
    r, w, v = align(r, w, v)
    return jnp.sum(w * -jnp.expm1(-r * r / (2 * v)), axis=-2)


# --- fitting ------------------------------------------------------------------


def _nnls(A: np.ndarray, b: np.ndarray, iters: int = 500) -> np.ndarray:
    """Non-negative least squares min |A x - b|, x >= 0 (Lawson & Hanson 1974, ch. 23)."""
    m, n = A.shape
    x = np.zeros(n)
    passive = np.zeros(n, bool)
    w = A.T @ (b - A @ x)
    tol = 10 * np.finfo(float).eps * np.linalg.norm(A, 1) * max(m, n)
    for _ in range(iters):
        if passive.all() or w[~passive].max(initial=-np.inf) <= tol:
            break
        j = np.argmax(np.where(passive, -np.inf, w))
        passive[j] = True
        while True:
            z = np.zeros(n)
            z[passive] = np.linalg.lstsq(A[:, passive], b, rcond=None)[0]
            if np.all(z[passive] > 0):
                x = z
                break
            neg = passive & (z <= 0)
            alpha = np.min(x[neg] / (x[neg] - z[neg]))
            x = x + alpha * (z - x)
            passive &= x > tol
            x[~passive] = 0
        w = A.T @ (b - A @ x)
    return x


def fit_sum_of_gaussians(
    profile: AbstractProfile,
    n: int = 6,
    variances: ArrayLike | None = None,
    r_max: float | None = None,
) -> SumOfGaussians:
    """A sum of Gaussians fitted to any radial profile, per channel (offline, NumPy; not differentiable).

    Minimises integral_0^r_max r (R(r) - sum_k w_k G(v_k, r))^2 dr over w >= 0 by non-negative least squares,
    with the energy constraint sum_k w_k = ``profile.total()`` imposed exactly (a heavily weighted row, then a
    final rescale), so the fit conserves the profile's albedo.

    Args:
        profile: one radial profile (parameters of shape [C]).
        n: the number of Gaussians when ``variances`` is None.
        variances: the Gaussians' variances (mm^2, [K]); None: ``n`` values spaced geometrically between the
            squared radii holding 2 % and 99.8 % of the energy of the narrowest and widest channel, then refined by
            a coordinate search on the spacing.
        r_max: the upper limit of the fitted radii (mm); None: 1.5 x the radius holding 99.8 % of the widest
            channel's energy.

    Returns:
        The ``SumOfGaussians``.

    References:
        d'Eon, Luebke and Enderton 2007, "Efficient rendering of human skin", sec. 3 (the error minimised).
    """
    if profile.batch_shape != ():
        raise ValueError(
            f"fit_sum_of_gaussians: profile parameters must have shape [C], got batch {profile.batch_shape}"
        )
    total = np.asarray(profile.total(), float)
    lo = float(np.min(np.asarray(energy_radius(profile, 0.02))))
    hi = float(np.max(np.asarray(energy_radius(profile, 0.998))))
    if r_max is None:
        r_max = 1.5 * hi
    # quadrature nodes: geometric panels resolve both the peak and the tail
    x, wq = np.polynomial.legendre.leggauss(16)
    edges = np.concatenate([[0.0], np.geomspace(max(lo * 1e-3, 1e-9), r_max, 80)])
    a, b = edges[:-1, None], edges[1:, None]
    r = (0.5 * (b - a) * x + 0.5 * (a + b)).ravel()
    wr = (0.5 * (b - a) * wq).ravel() * r  # the r weight of the error norm
    target = np.asarray(profile.radial(jnp.asarray(r)), float)  # [N, C]
    sq = np.sqrt(wr)

    def solve(v):
        G = np.exp(-r[:, None] ** 2 / (2 * v[None, :])) / (2 * np.pi * v[None, :])  # [N, K]
        scale = np.sqrt(np.sum((sq[:, None] * target) ** 2, axis=0)) + 1e-300
        W, err = [], 0.0
        for c in range(target.shape[1]):
            # the energy row: weight 1e3 x the residual norm, so it holds to ~1e-3 before the rescale
            lam = 1e3 * scale[c] / max(total[c], 1e-300)
            A = np.vstack([sq[:, None] * G, lam * np.ones((1, len(v)))])
            y = np.concatenate([sq * target[:, c], [lam * total[c]]])
            wc = _nnls(A, y)
            s = wc.sum()
            wc = wc * (total[c] / s) if s > 0 else wc
            W.append(wc)
            err += np.sum((sq * (G @ wc - target[:, c])) ** 2) / scale[c] ** 2
        return np.stack(W, axis=-1), err

    if variances is not None:
        v = np.asarray(variances, float)
        if v.ndim != 1 or np.any(v <= 0):
            raise ValueError(f"fit_sum_of_gaussians: variances must be positive with shape [K], got {v!r}")
        W, _ = solve(v)
        return SumOfGaussians(jnp.asarray(W), jnp.asarray(v))
    if n < 1:
        raise ValueError(f"fit_sum_of_gaussians: n must be >= 1, got {n}")
    lv0, lv1 = np.log((lo / 2) ** 2), np.log((hi / 2.5) ** 2)
    best = solve(np.exp(np.linspace(lv0, lv1, n)))[1], lv0, lv1
    step = 0.5
    for _ in range(12):  # coordinate search on the two ends of the geometric grid
        improved = False
        for d0, d1 in ((step, 0), (-step, 0), (0, step), (0, -step)):
            a0, a1 = best[1] + d0, best[2] + d1
            if a1 <= a0:
                continue
            e = solve(np.exp(np.linspace(a0, a1, n)))[1]
            if e < best[0]:
                best, improved = (e, a0, a1), True
        if not improved:
            step /= 2
    v = np.exp(np.linspace(best[1], best[2], n))
    W, _ = solve(v)
    return SumOfGaussians(jnp.asarray(W, jnp.result_type(float)), jnp.asarray(v, jnp.result_type(float)))
