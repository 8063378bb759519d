"""``Fast``, the "fast" method (order-2 SH irradiance at the bent normal x ambient occlusion, and
split-sum specular), and its precomputation (shared with ``Dense``): area-weighted
lat-long resampling, the GGX-prefiltered environment (split-sum, Karis 2013)
and its DFG lookup table, and the average Fresnel transmittance for diffuse
light entering a dielectric.

Split-sum approximation (Karis 2013, "Real Shading in Unreal Engine 4", eq. 4):

    int L(l) f(l, v) cos_l dl  ~=  [ int L(l) D(h) cos_l dl / int D(h) cos_l dl ]
                                   x [ int f(l, v) cos_l dl ]

The first factor is the environment prefiltered with the GGX lobe around the
reflection direction (assuming n = v = r), tabulated on lat-long maps for a
ladder of roughnesses; it is computed here by filtered importance sampling
(Krivanek & Colbert 2008, "Real-time Shading with Filtered Importance
Sampling", eq. 6-7): N GGX samples per texel, each looking the map up at the
mip level whose texel matches the sample's solid angle. The second factor,
for Schlick's Fresnel, is F0 A(cos_v, alpha) + B(cos_v, alpha) with A, B
tabulated once (the "DFG" LUT), here by visible-normal importance sampling
(Heitz 2018), for which the separable-Smith estimator is F G1(l) exactly.
"""

from __future__ import annotations

import functools
import math
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

import brdf
import skin_bssrdf

from ..envmap._latlong import EnvMap, latlong_directions, latlong_solid_angles, sample_latlong
from ..envmap._sh import sh_irradiance, sh_project
from ..materials._maps import BLINN_PHONG, GGX, GGX_ANISO, SUBSURFACE
from ._abstract import AbstractMethod, int_at_least
from ._directional import direction_visibility
from ._shading import env_rotation

# Roughness ladder of the prefiltered levels: alpha_k = (k / (K - 1))^2, i.e. equal
# steps in sqrt(alpha) ("perceptual roughness", Karis 2013), 0 (the mirror) to 1.
DEFAULT_LEVELS = 7
# Rows of the finest prefiltered level (and of the mip chain's base): 128 rows
# = 1.4 degrees per texel, finer than a GGX lobe of alpha ~0.03.
DEFAULT_PREFILTER_ROWS = 128
# GGX samples per prefiltered texel (filtered importance sampling needs few).
DEFAULT_PREFILTER_SAMPLES = 64
# Coarsest rows of any prefiltered level.
_MIN_LEVEL_ROWS = 16
# DFG table: cos_v x sqrt(alpha) cells and VNDF samples per cell.
DEFAULT_LUT_SIZE = 32
_LUT_SAMPLES = 512


def area_resample(radiance: Array, rows: int) -> Array:
    """Resample a lat-long map [H, 2H, C] to ``rows`` x 2 ``rows`` pixels,
    each the solid-angle-weighted mean of the piecewise-constant map over the
    new pixel (exact when ``H`` is a multiple of ``rows``; otherwise the map is
    first refined by nearest lookup to a common multiple grid, which keeps it
    piecewise constant, then averaged). Conserves the integral
    ``sum L dOmega`` (to the refinement's rounding)."""
    rad = jnp.asarray(radiance)
    h, w, c = rad.shape
    rows = int(rows)
    if rows == h:
        return rad
    if h % rows == 0:
        fine, f = rad, h // rows
    else:
        f = max(1, math.ceil(h / rows)) * (4 if rows > h else 2)
        dirs = latlong_directions(rows * f, 2 * rows * f, rad.dtype)
        fine = sample_latlong(rad, dirs, "nearest")
    fh = fine.shape[0]
    dom = latlong_solid_angles(fh, 2 * fh, rad.dtype)[..., None]
    num = (fine * dom).reshape(rows, f, 2 * rows, f, c).sum(axis=(1, 3))
    den = dom.reshape(rows, f, 2 * rows, f, 1).sum(axis=(1, 3))
    return num / den


def _mip_chain(base: Array) -> tuple[Array, ...]:
    """Area-averaged 2x reductions of ``base`` down to 4 rows."""
    out = [base]
    while out[-1].shape[0] >= 8 and out[-1].shape[0] % 2 == 0:
        out.append(area_resample(out[-1], out[-1].shape[0] // 2))
    return tuple(out)


def _hammersley(n: int) -> np.ndarray:
    """n points of the 2-D Hammersley set in [0, 1)^2 (radical inverse base 2)."""
    i = np.arange(n, dtype=np.uint64)
    rev = np.zeros(n, np.uint64)
    x = i.copy()
    for _ in range(32):
        rev = (rev << np.uint64(1)) | (x & np.uint64(1))
        x >>= np.uint64(1)
    return np.stack([(np.arange(n) + 0.5) / n, rev.astype(np.float64) / 2.0**32], axis=1)


@functools.partial(jax.jit, static_argnames=("rows", "n_samples"))
def _prefilter_levels(mips: tuple[Array, ...], alphas: Array, rows: int, n_samples: int) -> Array:
    """Prefiltered maps [K, rows, 2 rows, C] for the roughnesses ``alphas`` [K]:
    for each texel direction r (taken as n = v = r), sum_k L(l_k) cos(l_k) /
    sum_k cos(l_k) over GGX-sampled half vectors, each lookup at mip level
    0.5 log2(Omega_sample / Omega_texel) + 1 (Karis 2013's bias), blended
    linearly between mips. One compilation for all levels (lax.map over alpha)."""
    dt = mips[0].dtype
    u = jnp.asarray(_hammersley(n_samples), dt)
    r = latlong_directions(rows, 2 * rows, dt).reshape(-1, 3)
    t, b = brdf.orthonormal_basis(r)  # any frame about r (Duff et al. 2017): the lobe is isotropic
    h0 = mips[0].shape[0]
    omega_texel = 4.0 * jnp.pi / (2.0 * h0 * h0)

    def level(alpha):
        # GGX half vectors around +z: tan^2(theta_h) = alpha^2 u / (1 - u).
        t2 = alpha * alpha * u[:, 0] / (1.0 - u[:, 0])
        cos_h = 1.0 / jnp.sqrt(1.0 + t2)
        sin_h = jnp.sqrt(jnp.maximum(1.0 - cos_h * cos_h, 0.0))
        phi = 2.0 * jnp.pi * u[:, 1]
        h_loc = jnp.stack([sin_h * jnp.cos(phi), sin_h * jnp.sin(phi), cos_h], axis=-1)  # [N, 3]
        # l = reflect(v = z, h); its pdf is D cos_h / (4 v.h) = D / 4.
        l_loc = 2.0 * cos_h[:, None] * h_loc - jnp.asarray([0.0, 0.0, 1.0], dt)[None, :]
        a2 = jnp.maximum(alpha * alpha, 1e-12)
        pdf = a2 / (jnp.pi * (cos_h**2 * (a2 - 1.0) + 1.0) ** 2) / 4.0
        omega_s = 1.0 / (n_samples * jnp.maximum(pdf, 1e-30))
        lod = jnp.clip(0.5 * jnp.log2(omega_s / omega_texel) + 1.0, 0.0, len(mips) - 1.0)  # [N]
        wgt = jnp.maximum(l_loc[:, 2], 0.0)  # [N]
        dirs = l_loc[:, 0:1, None] * t[None] + l_loc[:, 1:2, None] * b[None] + l_loc[:, 2:3, None] * r[None]
        acc = jnp.zeros(r.shape[:1] + mips[0].shape[-1:], dt)
        for k, m in enumerate(mips):
            hat = jnp.maximum(1.0 - jnp.abs(lod - k), 0.0) * wgt  # [N]
            acc = acc + jnp.einsum("n,nrc->rc", hat, sample_latlong(m, dirs))
        return (acc / jnp.sum(wgt)).reshape(rows, 2 * rows, -1)

    return jax.lax.map(level, alphas)


def prefilter_levels(radiance: Array, levels: int = DEFAULT_LEVELS, rows: int = DEFAULT_PREFILTER_ROWS,
                     samples: int = DEFAULT_PREFILTER_SAMPLES) -> tuple[tuple[Array, ...], np.ndarray]:
    """GGX-prefiltered lat-long maps for alpha_k = (k / (levels - 1))^2: level 0
    is the map itself (area-resampled to ``rows``), levels k >= 1 have half
    as many rows (at least 16). Returns (levels, alphas)."""
    if levels < 2:
        raise ValueError(f"fast method: levels must be >= 2, got {levels}")
    h = jnp.asarray(radiance).shape[0]
    base = area_resample(radiance, min(int(rows), h))
    mips = _mip_chain(base)
    alphas = (np.arange(levels) / (levels - 1.0)) ** 2
    r = min(max(_MIN_LEVEL_ROWS, base.shape[0] // 2), base.shape[0])
    pre = _prefilter_levels(mips, jnp.asarray(alphas[1:], base.dtype), int(r), int(samples))
    return (base,) + tuple(pre[k] for k in range(levels - 1)), alphas


def lookup_prefiltered(levels: tuple[Array, ...], alpha: Array, r: Array) -> Array:
    """Prefiltered radiance [P, C] in world directions r [P, 3] at roughness
    alpha [P, 1], linear in sqrt(alpha) between the two nearest levels."""
    k_max = len(levels) - 1
    s = jnp.clip(jnp.sqrt(jnp.maximum(alpha, 0.0)) * k_max, 0.0, float(k_max))  # [P, 1]
    out = None
    for k, lev in enumerate(levels):
        hat = jnp.maximum(1.0 - jnp.abs(s - k), 0.0)
        v = hat * sample_latlong(lev, r)
        out = v if out is None else out + v
    return out


@functools.lru_cache(maxsize=4)
def dfg_lut(size: int = DEFAULT_LUT_SIZE, samples: int = _LUT_SAMPLES) -> np.ndarray:
    """The split-sum DFG table [size (cos_v), size (sqrt alpha), 2]: (A, B) with
    int f_GGX(l, v) cos_l dl = F0 A + B for Schlick's Fresnel and separable
    Smith masking (the model of ``relight.LadderBRDF``). Cell centres
    cos_v = (i + 0.5) / size, sqrt(alpha) = (j + 0.5) / size. Computed in JAX
    (float64 when enabled) by visible-normal sampling: the estimator of
    f cos_l / pdf is F(v.h) G1(l) (Heitz 2018, sec. 2), averaged over a
    Hammersley set. Evaluated eagerly (concrete) even inside an outer jit."""
    with jax.ensure_compile_time_eval():
        return _dfg_lut(size, samples)


def _dfg_lut(size: int, samples: int) -> np.ndarray:
    a, b = _dfg_lut_jit(size, samples)
    return np.stack([np.asarray(a), np.asarray(b)], -1).reshape(size, size, 2)


@functools.partial(jax.jit, static_argnums=(0, 1))
def _dfg_lut_jit(size: int, samples: int):
    dt = jnp.result_type(float)
    mu = (np.arange(size) + 0.5) / size
    ra = (np.arange(size) + 0.5) / size
    u = jnp.asarray(_hammersley(samples), dt)
    mu_g, a_g = np.meshgrid(mu, ra ** 2, indexing="ij")
    mu_j = jnp.asarray(mu_g.reshape(-1, 1, 1), dt)
    a_j = jnp.asarray(a_g.reshape(-1, 1, 1), dt)
    wo = jnp.concatenate([jnp.sqrt(1.0 - mu_j * mu_j), jnp.zeros_like(mu_j), mu_j], axis=-1)  # [G, 1, 3]
    wo = jnp.broadcast_to(wo, (wo.shape[0], samples, 3))
    ggx = brdf.GGX(jnp.broadcast_to(a_j, wo.shape[:2] + (1,)))
    wm = ggx.sample_wm(wo, jnp.broadcast_to(u[None], wo.shape[:2] + (2,)))
    vh = jnp.sum(wo * wm, axis=-1, keepdims=True)
    wi = 2.0 * vh * wm - wo
    g1 = ggx.G1(wi)
    fc = (1.0 - jnp.clip(vh, 0.0, 1.0)) ** 5
    up = wi[..., 2:3] > 0
    a = jnp.mean(jnp.where(up, (1.0 - fc) * g1, 0.0), axis=(1, 2))
    b = jnp.mean(jnp.where(up, fc * g1, 0.0), axis=(1, 2))
    return a, b


def lookup_dfg(lut: Array, cos_v: Array, alpha: Array) -> Array:
    """Bilinear lookup of the DFG table (cell centres, clamped at the edges):
    [P, 1] cos_v and alpha -> [P, 2] (A, B)."""
    n = lut.shape[0]
    x = jnp.clip(cos_v * n - 0.5, 0.0, n - 1.0)
    y = jnp.clip(jnp.sqrt(jnp.maximum(alpha, 0.0)) * n - 0.5, 0.0, n - 1.0)
    x0 = jnp.floor(x)
    y0 = jnp.floor(y)
    fx, fy = x - x0, y - y0
    i0 = x0[:, 0].astype(jnp.int32)
    j0 = y0[:, 0].astype(jnp.int32)
    i1 = jnp.minimum(i0 + 1, n - 1)
    j1 = jnp.minimum(j0 + 1, n - 1)
    top = lut[i0, j0] * (1 - fy) + lut[i0, j1] * fy
    bot = lut[i1, j0] * (1 - fy) + lut[i1, j1] * fy
    return top * (1 - fx) + bot * fx


@functools.lru_cache(maxsize=8)
def mean_transmittance(eta: float) -> float:
    """Cosine-weighted mean Fresnel transmittance into a dielectric of relative
    index eta under uniform illumination, 1 - 2 int_0^1 F(mu) mu dmu (the
    complement of the external diffuse Fresnel reflectance)."""
    x, w = np.polynomial.legendre.leggauss(64)
    mu = 0.5 * (x + 1.0)
    with jax.ensure_compile_time_eval():
        f = np.asarray(brdf.fresnel_dielectric(jnp.asarray(mu[:, None]), float(eta)))[:, 0]
    return float(1.0 - 2.0 * np.sum(0.5 * w * f * mu))


# Default samples per chunk of the fast kernel.
_CHUNK_FAST = 16384


class FastLighting(eqx.Module):
    """``Fast``'s prepared lighting: order-2 SH coefficients ``sh`` [9, C], the GGX-prefiltered
    ``levels`` and the DFG table ``lut`` [n, n, 2]."""

    sh: Any
    levels: Any
    lut: Any
    dtype: Any = eqx.field(static=True)


class FastGeometry(eqx.Module):
    """``Fast``'s geometry: ambient occlusion ``ao`` [P, 1] and bent normals ``bent`` [P, 3] (None:
    the shading normals, nothing occluded)."""

    ao: Any
    bent: Any = None


@jax.jit
def _fast_kernel(m, wo, ao, bent, rot, sh, levels, lut, t_avg):
    """Split-sum specular + SH diffuse for one chunk (see ``Fast``).
    Returns (L_surface [Pc, C], E_subsurface [Pc, C])."""
    rho_d, rho_s, alpha, model, t, b, n = m
    model = model[:, None]
    cos_v = jnp.sum(wo * n, axis=-1, keepdims=True)
    # Irradiance at the bent normal (environment frame), scaled by ambient occlusion.
    e = jnp.maximum(sh_irradiance(sh, bent @ rot), 0.0) * ao
    diffuse = jnp.where(model < SUBSURFACE, rho_d / jnp.pi, 0.0) * e
    ax = alpha[:, 0:1]
    ay = jnp.where(model >= GGX_ANISO, alpha[:, 1:2], ax)
    a = jnp.sqrt(ax * ay)  # anisotropic lobes are treated as isotropic of the same area
    r = 2.0 * cos_v * n - wo
    pre = lookup_prefiltered(levels, a, r @ rot)
    ab = lookup_dfg(lut, jnp.clip(cos_v, 0.0, 1.0), a)
    ggx = pre * (rho_s * ab[:, 0:1] + ab[:, 1:2])
    spec = jnp.where(model >= GGX, ggx, jnp.where(model == BLINN_PHONG, pre * rho_s, 0.0))
    # Lagarde & de Rousiers 2014 (Moving Frostbite to PBR, sec. 4.10.2): specular occlusion from AO.
    so = jnp.clip((jnp.clip(cos_v, 0.0, 1.0) + ao) ** jnp.exp2(-16.0 * a - 1.0) - 1.0 + ao, 0.0, 1.0)
    out = jnp.where(cos_v > 0, diffuse + spec * so, 0.0)
    return out, e * t_avg


class Fast(AbstractMethod):
    """Order-2 SH irradiance at the bent normal x ambient occlusion, and split-sum specular with
    specular occlusion.

    Diffuse from the SH irradiance at the bent normal times ambient occlusion; specular by the
    split-sum approximation: the GGX-prefiltered environment x the DFG table, with Lagarde & de
    Rousiers' specular occlusion from the ambient occlusion. The subsurface term enters with the
    mean Fresnel transmittance.

    Args:
        levels: prefiltered roughness levels (>= 2).
        prefilter_rows: rows of the finest prefiltered level (>= 8).
        prefilter_samples: GGX samples per prefiltered texel (>= 1).
        ao_rays: visibility rays per sample for ambient occlusion and bent normals (>= 1).
        lut_size: the DFG table is ``lut_size`` x ``lut_size`` (>= 2).

    References:
        Ramamoorthi & Hanrahan 2001, "An Efficient Representation for Irradiance Environment Maps",
        eq. 7-9; Karis 2013, "Real Shading in Unreal Engine 4", eq. 4; Lagarde & de Rousiers 2014,
        "Moving Frostbite to PBR", sec. 4.10.2.
    """

    levels: int = DEFAULT_LEVELS
    prefilter_rows: int = DEFAULT_PREFILTER_ROWS
    prefilter_samples: int = DEFAULT_PREFILTER_SAMPLES
    ao_rays: int = 64
    lut_size: int = DEFAULT_LUT_SIZE

    name: ClassVar[str] = "fast"
    KEYWORDS: ClassVar[dict[str, str]] = {k: k for k in
                                          ("levels", "prefilter_rows", "prefilter_samples", "ao_rays", "lut_size")}

    def __check_init__(self):
        for f, lo in (("levels", 2), ("prefilter_rows", 8), ("prefilter_samples", 1), ("ao_rays", 1), ("lut_size", 2)):
            int_at_least("fast", f, getattr(self, f), lo)

    def prepare(self, env, *, dtype=jnp.float32) -> FastLighting:
        env = EnvMap(jnp.asarray(env.radiance, dtype))
        levels, _ = prefilter_levels(env.radiance, self.levels, self.prefilter_rows, self.prefilter_samples)
        return FastLighting(sh_project(env, 2), levels, jnp.asarray(dfg_lut(self.lut_size), dtype), dtype)

    def geometry(self, lighting: FastLighting, maps, surface, mesh=None, visibility=None, *,
                 terminator: bool = True) -> FastGeometry:
        if visibility is not None:
            raise ValueError(f"method {self.name!r} takes no visibility argument (it casts its own rays from mesh)")
        dt = lighting.dtype
        P = surface.num_samples
        if mesh is None:
            return FastGeometry(jnp.ones((P, 1), dt), None)
        dirs = brdf.fibonacci_sphere(self.ao_rays, axis=1)
        vis = direction_visibility(mesh, surface, dirs, terminator)  # [P, K]
        n = np.asarray(maps.frame(surface).normal, np.float64)
        cos = np.maximum(n @ dirs.T, 0.0) * (np.asarray(surface.normal, np.float64) @ dirs.T > 0)  # [P, K]
        tot = cos.sum(1, keepdims=True)
        ok = tot > 0
        ao = np.where(ok, (cos * vis).sum(1, keepdims=True) / np.where(ok, tot, 1.0), 1.0)
        # Bent normal: n moved by the cosine-weighted mean of the unoccluded directions minus that of
        # all directions (so it is n exactly when nothing is occluded, whatever the ray set's
        # discretisation).
        m_vis = np.where(ok, (cos * vis) @ dirs / np.maximum((cos * vis).sum(1, keepdims=True), 1e-12), 0.0)
        m_all = np.where(ok, cos @ dirs / np.where(ok, tot, 1.0), 0.0)
        bent = n + np.where(ao > 0, m_vis - m_all, 0.0)
        bent /= np.maximum(np.linalg.norm(bent, axis=1, keepdims=True), 1e-12)
        return FastGeometry(jnp.asarray(ao, dt), jnp.asarray(bent, dt))

    def default_chunk(self) -> int:
        return _CHUNK_FAST

    def chunk_shader(self, lighting: FastLighting, geometry: FastGeometry, *, rotation=None, key=None,
                     eta: float = skin_bssrdf.SKIN_ETA):
        dt = lighting.dtype
        rot = env_rotation(rotation, dt)
        t_avg = jnp.asarray(mean_transmittance(float(eta)), dt)

        def shader(chunk, want_sss):
            bent = chunk.m[6] if geometry.bent is None else chunk.take(geometry.bent)
            return _fast_kernel(chunk.m, chunk.wo, chunk.take(geometry.ao), bent, rot, lighting.sh, lighting.levels,
                                lighting.lut, t_avg)

        return shader
