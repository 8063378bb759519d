"""``Reference``: Monte Carlo with multiple importance sampling (Veach & Guibas 1995, balance or power
heuristic) of environment importance sampling (piecewise-constant 2-D distribution) and BRDF sampling
(GGX visible normals, Heitz 2018, mixed with cosine-weighted hemisphere sampling); ray-cast
visibility per sample direction. Unbiased for the piecewise-constant map."""

from __future__ import annotations

import functools
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

import brdf
import skin_bssrdf
import stage
from brdf import safe_normalize

from ..envmap._latlong import EnvMap, sample_latlong
from ..envmap._sampling import envmap_pdf, envmap_sampler, sample_envmap
from ..materials._maps import BLINN_PHONG, GGX_ANISO
from ._abstract import AbstractMethod, int_at_least
from ._shading import env_rotation, material

__all__ = ["Reference", "ReferenceGeometry", "ReferenceLighting"]

# Monte Carlo directions per pass (per sample): one compilation serves every sample count; more
# samples run more passes (averaged).
_MC_PASS = 64
# (sample x direction) pairs per chunk of the Monte Carlo kernel.
_MC_PAIRS = 1 << 18
# Lobe-selection probability of BRDF sampling: the specular share, clamped so that neither the GGX
# nor the cosine lobe is ever left unsampled where it matters.
_Q_SPEC_MIN, _Q_SPEC_MAX = 0.1, 0.9


def _latin_hypercube(key, rows: int, n: int, dims: int, dt) -> Array:
    """[rows, n, dims] uniforms, each dimension stratified into n jittered
    strata per row with an independent random order (Latin hypercube sampling,
    McKay et al. 1979): unbiased like iid uniforms, lower variance for
    integrands that are smooth along each dimension."""
    kp, kj = jax.random.split(key)
    perm = jnp.argsort(jax.random.uniform(kp, (rows, dims, n)), axis=-1)
    u = (jnp.swapaxes(perm, 1, 2).astype(dt) + jax.random.uniform(kj, (rows, n, dims), dt)) / n
    return jnp.minimum(u, 1.0 - jnp.finfo(dt).epsneg)


@functools.partial(jax.jit, static_argnames=("n_env", "n_brdf", "power", "want_sss", "horizon"))
def _mc_sample(m, ng, wo_in, key, rot, sampler, radiance, eta, n_env: int, n_brdf: int, power: bool, want_sss: bool,
               horizon: bool):
    """Stage 1 of the reference: sample directions by both strategies and
    return (world directions [Pc, N, 3], weighted contributions [Pc, N, C] for
    the surface term and for the subsurface irradiance), before visibility."""
    # Sampling and MIS weights see the parameters without gradient (the
    # directions and weights are held fixed, see below); only f_r, cos and L
    # carry derivatives, which also keeps the differentiated program small.
    rho_d, rho_s, alpha, model, t, b, n = jax.tree_util.tree_map(jax.lax.stop_gradient, m)
    wo = jax.lax.stop_gradient(wo_in)
    Pc = wo.shape[0]
    dt = wo.dtype
    k1, k2 = jax.random.split(key, 2)
    wo_l = stage.to_local(wo, t, b, n)  # [Pc, 3]
    wo_b = wo_l[:, None, :]
    dirs = []
    if n_env:
        u = _latin_hypercube(k1, Pc, n_env, 2, dt)
        d_env, _, _, _ = sample_envmap(sampler, u.reshape(Pc * n_env, 2))
        dirs.append((d_env @ rot.T).reshape(Pc, n_env, 3))
    ax = alpha[:, None, 0:1]
    ay = jnp.where(model[:, None, None] >= GGX_ANISO, alpha[:, None, 1:2], ax)
    micro = brdf.Microfacet(brdf.GGX(ax, ay), brdf.SchlickFresnel(rho_s[:, None, :]), "smith")
    wd = jnp.mean(rho_d, axis=-1, keepdims=True)
    ws = jnp.where(model[:, None] >= BLINN_PHONG, rho_s, 0.0)
    has_spec = ws > 0
    q = jnp.where(has_spec, jnp.clip(ws / jnp.maximum(ws + wd, 1e-12), _Q_SPEC_MIN, _Q_SPEC_MAX), 0.0)
    q = q[:, None, :]  # [Pc, 1, 1]
    if n_brdf:
        u3 = _latin_hypercube(k2, Pc, n_brdf, 3, dt)
        u2, sel = u3[..., 0:2], u3[..., 2:3]
        wo_n = jnp.broadcast_to(wo_b, (Pc, n_brdf, 3))
        wi_spec, _ = micro.sample(wo_n, u2)
        wi_cos = brdf.sample_cosine_hemisphere(u2)
        wi_l = jnp.where(sel < q, wi_spec, wi_cos)
        tt, bb, nn = t[:, None, :], b[:, None, :], n[:, None, :]
        dirs.append(safe_normalize(wi_l[..., 0:1] * tt + wi_l[..., 1:2] * bb + wi_l[..., 2:3] * nn))
    d = jax.lax.stop_gradient(jnp.concatenate(dirs, axis=1) if len(dirs) > 1 else dirs[0])  # [Pc, N, 3]
    N = n_env + n_brdf
    d_env = d @ rot  # R^T d (row vectors)
    L = sample_latlong(radiance, d_env, "nearest")  # [Pc, N, C]
    wi_all = stage.to_local(jnp.swapaxes(d, 0, 1), t, b, n)  # [N, Pc, 3]
    wi_all = jnp.swapaxes(wi_all, 0, 1)  # [Pc, N, 3]
    wo_all = jnp.broadcast_to(wo_b, (Pc, N, 3))
    # The same directions in the differentiable frame, for f_r and the cosine.
    wi_f = jnp.swapaxes(stage.to_local(jnp.swapaxes(d, 0, 1), m[4], m[5], m[6]), 0, 1)
    wo_f = jnp.broadcast_to(stage.to_local(wo_in, m[4], m[5], m[6])[:, None, :], (Pc, N, 3))
    p_e = envmap_pdf(sampler, d_env)[..., None] * n_env  # [Pc, N, 1], times the sample counts
    p_spec = jnp.where(q > 0, micro.pdf(wo_all, wi_all), 0.0)
    p_b = (q * p_spec + (1.0 - q) * brdf.pdf_cosine_hemisphere(wi_all)) * n_brdf
    from_env = (jnp.arange(N) < n_env)[None, :, None]
    if power:
        p_s = jnp.where(from_env, p_e, p_b)
        den = p_e * p_e + p_b * p_b
    else:
        p_s = jnp.ones_like(p_e)
        den = p_e + p_b
    ok = den > 0
    mis = jnp.where(ok, p_s / jnp.where(ok, den, 1.0), 0.0)  # MIS weight / (n_s p_s)
    # Gradients: the sample directions and their weights are held fixed (the
    # estimator's derivative is then sum d(f cos L)/dtheta * weight, unbiased
    # for d/dtheta of the integral; differentiating the pdfs would add a
    # biased term and a large backward graph).
    mis = jax.lax.stop_gradient(mis)
    if horizon:
        up = jnp.sum(d * ng[:, None, :], axis=-1, keepdims=True) > 0
        mis = jnp.where(up, mis, 0.0)
    # Each direction is a light of radiance L, weighted: the OLAT forward model
    # of stage (f_r cos_i E, and F_t cos_i E into the medium) with E = L mis.
    e = L * mis
    g = stage.reflected_radiance(material(m, extra_axis=True), wi_f, wo_f, e)
    gs = stage.subsurface_irradiance(wi_f, e, eta) if want_sss else jnp.zeros_like(g)
    return d, g, gs


@jax.jit
def _mc_sum(g, gs, vis):
    v = vis[..., None]
    return jnp.sum(jnp.where(v, g, 0.0), axis=1), jnp.sum(jnp.where(v, gs, 0.0), axis=1)


class ReferenceLighting(eqx.Module):
    """``Reference``'s prepared lighting: the environment ``env`` and its importance-sampling tables
    ``sampler`` (held without gradient)."""

    env: EnvMap
    sampler: Any
    dtype: Any = eqx.field(static=True)


class ReferenceGeometry(eqx.Module):
    """``Reference``'s geometry: a ``stage.Occluder`` ray caster (None: no shadowing)."""

    rays: Any = None


class Reference(AbstractMethod):
    """Monte Carlo with multiple importance sampling of the environment and the BRDF.

    ``samples`` directions per sample (run in passes of 64, so rounded up to a multiple of 64 above
    64), ``env_fraction`` of them from environment sampling, the rest from BRDF sampling (GGX visible
    normals mixed with the cosine lobe); ray-cast visibility per direction. The directions and their
    MIS weights are held fixed under differentiation (an unbiased derivative estimator).

    Args:
        samples: directions per sample (>= 2).
        env_fraction: share of them from environment sampling, in [0, 1].
        heuristic: "power" (beta = 2) or "balance".

    References:
        Veach & Guibas 1995, "Optimally Combining Sampling Techniques for Monte Carlo Rendering",
        eq. 9 (balance) and 12 (power); Heitz 2018, "Sampling the GGX Distribution of Visible Normals".
    """

    samples: int = 256
    env_fraction: float | int = 0.5
    heuristic: str = "power"

    name: ClassVar[str] = "reference"
    KEYWORDS: ClassVar[dict[str, str]] = {"samples": "samples", "env_fraction": "env_fraction",
                                          "heuristic": "heuristic"}

    def __check_init__(self):
        int_at_least("reference", "samples", self.samples, 2)
        f = self.env_fraction
        if not (isinstance(f, (int, float)) and not isinstance(f, bool) and 0.0 <= f <= 1.0):
            raise ValueError(f"method 'reference': env_fraction must be in [0, 1], got {f!r}")
        if self.heuristic not in ("balance", "power"):
            raise ValueError(f"method 'reference': heuristic must be 'balance' or 'power', got {self.heuristic!r}")

    def prepare(self, env, *, dtype=jnp.float32) -> ReferenceLighting:
        env = EnvMap(jnp.asarray(env.radiance, dtype))
        return ReferenceLighting(env, jax.tree_util.tree_map(jax.lax.stop_gradient, envmap_sampler(env)), dtype)

    def geometry(self, lighting: ReferenceLighting, maps, surface, mesh=None, visibility=None, *,
                 terminator: bool = True) -> ReferenceGeometry:
        if visibility is not None:
            raise ValueError(f"method {self.name!r} takes no visibility argument (it casts its own rays from mesh)")
        return ReferenceGeometry(None if mesh is None else stage.Occluder(mesh, surface, terminator))

    def default_chunk(self) -> int:
        return max(16, _MC_PAIRS // min(self.samples, _MC_PASS))

    def chunk_shader(self, lighting: ReferenceLighting, geometry: ReferenceGeometry, *, rotation=None, key=None,
                     eta: float = skin_bssrdf.SKIN_ETA):
        rot = env_rotation(rotation, lighting.dtype)
        per_pass = min(self.samples, _MC_PASS)
        passes = -(-self.samples // per_pass)
        n_env = int(round(per_pass * self.env_fraction))
        n_brdf = per_pass - n_env
        key = jax.random.PRNGKey(0) if key is None else key
        rays = geometry.rays

        def shader(chunk, want_sss):
            out = e = None
            for p_ in range(passes):
                kp = jax.random.fold_in(jax.random.fold_in(key, chunk.number), p_)
                d, g, gs = _mc_sample(chunk.m, chunk.geometric_normal, chunk.wo, kp, rot, lighting.sampler,
                                      lighting.env.radiance, float(eta), n_env, n_brdf, self.heuristic == "power",
                                      want_sss, rays is not None)
                if rays is None:
                    vis = np.ones(d.shape[:2], bool)
                else:
                    active = np.asarray(jnp.any(g > 0, axis=-1) | jnp.any(gs > 0, axis=-1))
                    vis = rays.visible(chunk.index, np.asarray(d, np.float64), active)
                o, ee = _mc_sum(g, gs, jnp.asarray(vis))
                out, e = (o / passes, ee / passes) if out is None else (out + o / passes, e + ee / passes)
            return out, e

        return shader
