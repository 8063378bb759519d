"""Model-based relighting of surface samples: outgoing radiance toward a view
direction from material maps under an environment map, by four methods.

Everything computes the direct-lighting reflection equation with the
environment as the only light (pbrt-v4 eq. 4.14 / Kajiya 1986 without
interreflection):

    L_o(x, wo) = int_S2 f_r(x, wi, wo) max(0, n.wi) L_env(R^T wi) V(x, wi) dwi
                 + [model = SUBSURFACE] F_t(eta, n.wo) / pi * M(x)

    M(x) = sum_j w_xj E_j,  E_j = int F_t(eta, n.wi) max(0, n.wi) L_env(R^T wi) V(x_j, wi) dwi

(f_r the sample's :class:`relight.LadderBRDF`; V the ray-cast visibility,
including the geometric horizon; the subsurface term is Jensen et al. 2001's
diffusion BSSRDF, eq. 5, through ``skin_bssrdf.DiffusionOperator``, exactly as
``stage.simulate`` applies it; R an optional rotation of the environment).
Radiance is in the environment map's units (radiance per sr).

Methods (``method=``):

* ``"rig"``: the environment sampled at a light rig's lights with
  ``relight.envmap.light_weights`` (Debevec et al. 2000): the rig's OLAT
  reflection, near-field falloff included, weighted per light. What an OLAT
  capture supports; equal to ``relight_olat`` of ``stage.simulate`` of the
  same maps on the same rig.
* ``"dense"``: the midpoint rule over the pixels of the environment
  area-resampled to ``resolution`` x 2 ``resolution``, each pixel a distant
  light with ray-cast visibility.
* ``"lights"``: the environment cut by median cut (Debevec 2005) into
  ``lights`` regions of equal energy, each a distant light at its energy
  centroid carrying the region's exact integral, with ray-cast visibility.
* ``"fast"``: diffuse from order-2 SH irradiance (Ramamoorthi & Hanrahan 2001,
  eq. 7-9) at the bent normal times ambient occlusion; specular by the
  split-sum approximation (Karis 2013): GGX-prefiltered environment x DFG
  table, with Lagarde & de Rousiers 2014's specular occlusion (eq. in sec. 4.10.2).
* ``"reference"``: Monte Carlo with multiple importance sampling (Veach & Guibas
  1995, balance or power heuristic) of environment importance sampling
  (piecewise-constant 2-D distribution) and BRDF sampling (GGX visible normals,
  Heitz 2018, mixed with cosine-weighted hemisphere sampling); ray-cast
  visibility per sample direction. Unbiased for the piecewise-constant map.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import brdf
import stage
from brdf import safe_normalize

from ..envmap._latlong import EnvMap, latlong_directions, latlong_solid_angles, sample_latlong
from ..envmap._sampling import envmap_pdf, envmap_sampler, sample_envmap
from ..envmap._sh import sh_irradiance, sh_project
from ..envmap._weights import light_weights, light_weights_barycentric
from ..materials._maps import BLINN_PHONG, GGX, GGX_ANISO, SUBSURFACE, LadderBRDF, MaterialMaps
from . import _fast as fast
from ._lights import median_cut, region_strength
from ._options import _BY_NAME, METHODS, AbstractMethod, _int_at_least, resolve_method

__all__ = ["METHODS", "DEFAULTS", "render_samples"]

# Settings of each method and their defaults (documented in render_samples and
# on the method objects of relight.render._options, their one home).
DEFAULTS: dict[str, dict[str, Any]] = {name: cls().settings() for name, cls in _BY_NAME.items()}
_COMMON = {"chunk": None, "eta": 1.4, "operator": None, "rotation": None, "dtype": jnp.float32, "terminator": True}

# Directions (lights or environment pixels) per step of the scan inside the
# directional kernel: the working set is chunk x _DIR_BLOCK x C floats (~10
# temporaries of 4096 x 64 x 3 float32 ~ 30 MB).
_DIR_BLOCK = 64
# Directions per kernel call (padded): one compilation serves every rig and
# dense resolution; larger sets loop over calls. Sets smaller than that are
# padded to the next power of two >= _DIR_BLOCK only (64 or 128: at most three
# compilations), so a 64-light set does not pay for 256 directions.
_DIR_CALL = 256
# Monte Carlo directions per pass (per sample): one compilation serves every
# sample count; more samples run more passes (averaged).
_MC_PASS = 64
# Default samples per chunk of the directional ("rig", "dense") and "fast" kernels.
_CHUNK_DIRECTIONAL = 4096
_CHUNK_FAST = 16384
# (sample x direction) pairs per chunk of the Monte Carlo kernel.
_MC_PAIRS = 1 << 18
# A distant light for stage.light_visibility: a point this far along its direction (mm).
_FAR_MM = 1e3
# Lobe-selection probability of BRDF sampling: the specular share, clamped so
# that neither the GGX nor the cosine lobe is ever left unsampled where it matters.
_Q_SPEC_MIN, _Q_SPEC_MAX = 0.1, 0.9


# --------------------------------------------------------------------------- validation

def _settings(method, settings: dict) -> dict:
    """The resolved settings: the method object (``settings["method"]``, from a
    string name and its keywords or given as an object, validated when built)
    and its settings flattened under their keyword names, plus the settings
    every method shares (checked here)."""
    m, rest = resolve_method(method, settings)
    unknown = sorted(set(rest) - set(_COMMON))
    if unknown:
        raise ValueError(f"method {m.name!r} has no setting(s) {unknown}; its settings are "
                         f"{sorted(set(_COMMON) | set(type(m).KEYWORDS))}")
    out = {**_COMMON, **rest, **m.settings(), "method": m}
    if out["chunk"] is not None:
        _int_at_least(m.name, "chunk", out["chunk"], 1)
        out["chunk"] = int(out["chunk"])
    if not (isinstance(out["eta"], (int, float)) and out["eta"] >= 1.0):
        raise ValueError(f"setting 'eta' (relative index of refraction) must be a float >= 1, got {out['eta']!r}")
    if not isinstance(out["terminator"], bool):
        raise ValueError(f"setting 'terminator' must be True or False, got {out['terminator']!r}")
    if out["rotation"] is not None:
        r = np.asarray(out["rotation"], np.float64)
        if r.shape != (3, 3) or not np.all(np.isfinite(r)) or not np.allclose(r @ r.T, np.eye(3), atol=1e-4):
            raise ValueError(f"setting 'rotation' must be a 3x3 rotation matrix, got {r.shape} / not orthonormal")
    return out


def check_inputs(maps, surface, env, wo_world=None):
    """Types and sizes of the shared inputs (ValueError naming the problem)."""
    if not isinstance(maps, MaterialMaps):
        raise ValueError(f"maps must be a relight.MaterialMaps, got {type(maps).__name__}")
    if not isinstance(surface, stage.Surface):
        raise ValueError(f"surface must be a stage.Surface, got {type(surface).__name__}")
    if not isinstance(env, EnvMap):
        raise ValueError(f"env must be a relight.envmap.EnvMap (lat-long), got {type(env).__name__}")
    if env.radiance.shape[-1] != maps.rho_d.shape[-1]:
        raise ValueError(f"env has {env.radiance.shape[-1]} channels but the maps' rho_d has {maps.rho_d.shape[-1]}")
    P = surface.num_samples
    if maps.num_samples != P:
        raise ValueError(f"maps have {maps.num_samples} samples but the surface has {P}: "
                         "they must describe the same samples")
    shapes = {"rho_d": (P, 3), "rho_s": (P, 1), "alpha": (P, 2), "normal": (P, 3), "tangent": (P, 3), "mfp": (P, 3),
              "model": (P,)}
    for name, shp in shapes.items():
        got = tuple(getattr(maps, name).shape)
        if got != shp:
            raise ValueError(f"maps.{name} must have shape {list(shp)}, got {list(got)}")
    if wo_world is None:
        return None
    wo = jnp.asarray(wo_world)
    if wo.shape == (3,):
        wo = jnp.broadcast_to(wo, (P, 3))
    if wo.shape != (P, 3):
        raise ValueError(f"wo_world must be [P, 3] = [{P}, 3] or [3], got {list(wo.shape)}")
    return wo


# --------------------------------------------------------------------------- ray casting
# Occlusion queries along arbitrary directions (the Monte Carlo reference) are
# stage.Occluder's: the one ray caster, with the same ray origins (off the
# geometric normal, from the shadow-terminator point) and horizon test as
# stage.light_visibility.

def direction_visibility(mesh: stage.Mesh, surface: stage.Surface, directions: np.ndarray,
                         terminator: bool = True) -> np.ndarray:
    """bool [P, D]: sample p sees distant direction d (``stage.light_visibility``
    with a distant rig whose lights are ``directions``; ``terminator`` as there)."""
    d = np.asarray(directions, np.float64)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    with jax.ensure_compile_time_eval():  # concrete under an outer jit: the ray caster reads it on the host
        rig = stage.Rig(position=jnp.asarray(d * _FAR_MM, jnp.float32), intensity=jnp.ones((len(d), 1), jnp.float32),
                        solid_angle=jnp.full((len(d),), 4 * np.pi / len(d), jnp.float32), near_field=False)
    return np.asarray(stage.light_visibility(mesh, surface, rig, terminator=terminator))


def _rows(vis, idx: np.ndarray) -> np.ndarray:
    if isinstance(vis, stage.PackedMask):
        return np.unpackbits(vis.bits[idx], axis=-1, count=vis.n).astype(bool)
    return np.asarray(vis)[idx]


# --------------------------------------------------------------------------- lighting (env-dependent)

@dataclasses.dataclass
class Lighting:
    """What a method precomputes from the environment alone (reused for any
    geometry, view or camera orbit; for an environment rotation too, except the
    rig's light weights, which are recomputed from rotated light directions)."""

    method: str
    settings: dict
    env: EnvMap
    dirs: Any = None          # rig / dense / lights: [D, 3] world directions (lights: of the unrotated map)
    strength: Any = None      # lights: [D, C] region integrals
    dom: Any = None           # dense: [D] solid angles
    lowres: Any = None        # dense: [h, 2h, C] area-resampled map
    rig: Any = None           # rig: stage.Rig
    sh: Any = None            # fast: [9, C]
    levels: Any = None        # fast: prefiltered maps
    lut: Any = None           # fast: [n, n, 2]
    sampler: Any = None       # reference: EnvSampler

    def num_directions(self) -> int:
        if self.method == "rig":
            return self.rig.num_lights
        if self.method in ("dense", "lights"):
            return int(self.dirs.shape[0])
        if self.method == "fast":
            return int(self.settings["ao_rays"])
        return 0


def _latlong_dirs_np(h: int) -> np.ndarray:
    """``relight.envmap.latlong_directions(h, 2 h)`` as concrete NumPy [2 h^2, 3]
    (evaluated at trace time, so concrete even under an outer jit / grad)."""
    with jax.ensure_compile_time_eval():
        return np.asarray(latlong_directions(h, 2 * h), np.float64).reshape(-1, 3)


def prepare_lighting(env: EnvMap, method: str, settings: dict) -> Lighting:
    s = settings
    dt = s["dtype"]
    env = EnvMap(jnp.asarray(env.radiance, dt))
    lt = Lighting(method, s, env)
    if method == "rig":
        lt.rig = stage.light_stage_x() if s["rig"] is None else s["rig"]
        pos = np.asarray(lt.rig.position, np.float64)
        lt.dirs = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    elif method == "dense":
        h = s["resolution"]
        lt.lowres = fast.area_resample(env.radiance, h)
        lt.dirs = _latlong_dirs_np(h)
        lt.dom = latlong_solid_angles(h, 2 * h, dt).reshape(-1)
    elif method == "lights":
        # The partition (and the light directions) come from the map's values
        # without gradient; the strengths are exact region integrals of the
        # radiance, so derivatives flow to every pixel.
        with jax.ensure_compile_time_eval():
            conc = _concrete(jax.lax.stop_gradient(env.radiance))
        if conc is None:
            raise ValueError("method 'lights' cuts the environment into regions from its values: pass a concrete "
                             "env (not traced under jit); gradients with respect to it still flow")
        labels, dirs = median_cut(conc, s["lights"])
        lt.dirs = dirs
        lt.strength = region_strength(env.radiance, labels, len(dirs)).astype(dt)
    elif method == "fast":
        lt.sh = sh_project(env, 2)
        lt.levels, _ = fast.prefilter_levels(env.radiance, s["levels"], s["prefilter_rows"], s["prefilter_samples"])
        lt.lut = jnp.asarray(fast.dfg_lut(s["lut_size"]), dt)
    else:
        lt.sampler = jax.tree_util.tree_map(jax.lax.stop_gradient, envmap_sampler(env))
    return lt


def _strength(lt: Lighting, rotation) -> tuple[Array, Array, bool]:
    """(light positions or directions [D, 3], strength [D, C], near_field) for
    the directional kernel under the environment rotated by ``rotation``."""
    dt = lt.settings["dtype"]
    if lt.method == "rig":
        rig = lt.rig
        d = jnp.asarray(lt.dirs, dt)
        d_env = d if rotation is None else d @ jnp.asarray(rotation, dt)
        e = jnp.asarray(rig.center_irradiance, dt)
        if e.shape[-1] == 1:
            e = jnp.broadcast_to(e, (e.shape[0], lt.env.radiance.shape[-1]))
        fn = light_weights if lt.settings["weights"] == "voronoi" else light_weights_barycentric
        kw = {"supersample": lt.settings["supersample"]} if lt.settings["weights"] == "voronoi" else {}
        w = fn(lt.env, d_env, e, **kw).astype(dt)
        # w_l times the light's own strength: intensity (near field, divided by
        # the squared distance in the kernel) or irradiance (distant).
        inten = jnp.asarray(rig.intensity, dt)
        pos = jnp.asarray(rig.position, dt) if rig.near_field else d
        return pos, w * inten, bool(rig.near_field)
    if lt.method == "lights":
        d = jnp.asarray(lt.dirs, dt)
        # Light from d arrives from R d (row vectors: d R^T); exact, nothing is resampled.
        return (d if rotation is None else d @ jnp.asarray(rotation, dt).T), lt.strength, False
    # dense
    h = lt.lowres.shape[0]
    low = lt.lowres
    if rotation is not None:
        r = np.asarray(rotation, np.float64)
        ang = math.atan2(r[0, 2], r[0, 0])
        cols = ang / (2 * math.pi) * (2 * h)
        is_y = np.allclose(r, [[math.cos(ang), 0, math.sin(ang)], [0, 1, 0], [-math.sin(ang), 0, math.cos(ang)]],
                           atol=1e-6)
        if is_y and abs(cols - round(cols)) < 1e-3:
            # A rotation about y by whole pixels is an exact column roll (L_new(d) = L(R^T d)).
            low = jnp.roll(low, int(round(cols)), axis=1)
        else:
            low = sample_latlong(low, latlong_directions(h, 2 * h, dt) @ jnp.asarray(r, dt), "bilinear")
    strength = low.reshape(-1, low.shape[-1]) * lt.dom[:, None]
    return jnp.asarray(lt.dirs, dt), strength, False


# --------------------------------------------------------------------------- kernels

def _material(m, extra_axis: bool = False) -> LadderBRDF:
    rho_d, rho_s, alpha, model = m[0], m[1], m[2], m[3]
    if extra_axis:
        rho_d, rho_s, alpha = rho_d[:, None, :], rho_s[:, None, :], alpha[:, None, :]
        return LadderBRDF(rho_d, rho_s, alpha, model[:, None, None])
    return LadderBRDF(rho_d, rho_s, alpha, model[:, None])


@functools.partial(jax.jit, static_argnames=("near_field", "want_sss"))
def _directional_kernel(m, pos, wo, light, strength, vis, eta, near_field: bool, want_sss: bool):
    """sum over directions of f cos E V (and of F_t cos E V for subsurface)
    for one sample chunk; ``light`` [D, 3] positions (near field) or unit
    directions, ``strength`` [D, C], ``vis`` [Pc, D]; D a multiple of _DIR_BLOCK.

    The OLAT forward model of ``stage.simulate``, term for term:
    ``stage.incident_light`` (inverse square for near-field lights),
    ``stage.to_local``, ``stage.reflected_radiance_lights`` (f_r cos_i E V) and
    ``stage.subsurface_irradiance`` (F_t cos_i E V, Jensen et al. 2001 eq. 5)."""
    t, b, n = m[4], m[5], m[6]
    mat = _material(m)
    wo_l = stage.to_local(wo, t, b, n)
    D, C = strength.shape
    nb = D // _DIR_BLOCK
    xs = (light.reshape(nb, _DIR_BLOCK, 3), strength.reshape(nb, _DIR_BLOCK, C),
          vis.T.reshape(nb, _DIR_BLOCK, pos.shape[0]))

    def body(carry, x):
        lb, sb, vb = x
        wi, irr = stage.incident_light(lb, sb, near_field, pos)  # [B, Pc, 3], [B, Pc, C]
        wi_l = stage.to_local(wi, t, b, n)
        acc = carry[0] + jnp.sum(stage.reflected_radiance_lights(mat, wi_l, wo_l, irr, vb), axis=0)
        e = carry[1] + jnp.sum(stage.subsurface_irradiance(wi_l, irr, eta, vb), axis=0) if want_sss else carry[1]
        return (acc, e), None

    z = jnp.zeros((pos.shape[0], C), strength.dtype)
    (acc, e), _ = jax.lax.scan(body, (z, z), xs)
    return acc, e


@jax.jit
def _fast_kernel(m, wo, ao, bent, rot, sh, levels, lut, t_avg):
    """Split-sum specular + SH diffuse for one chunk (see the module docstring).
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
    pre = fast.lookup_prefiltered(levels, a, r @ rot)
    ab = fast.lookup_dfg(lut, jnp.clip(cos_v, 0.0, 1.0), a)
    ggx = pre * (rho_s * ab[:, 0:1] + ab[:, 1:2])
    spec = jnp.where(model >= GGX, ggx, jnp.where(model == BLINN_PHONG, pre * rho_s, 0.0))
    # Lagarde & de Rousiers 2014 (Moving Frostbite to PBR, sec. 4.10.2): specular occlusion from AO.
    so = jnp.clip((jnp.clip(cos_v, 0.0, 1.0) + ao) ** jnp.exp2(-16.0 * a - 1.0) - 1.0 + ao, 0.0, 1.0)
    out = jnp.where(cos_v > 0, diffuse + spec * so, 0.0)
    return out, e * t_avg


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
    g = stage.reflected_radiance(_material(m, extra_axis=True), wi_f, wo_f, e)
    gs = stage.subsurface_irradiance(wi_f, e, eta) if want_sss else jnp.zeros_like(g)
    return d, g, gs


@jax.jit
def _mc_sum(g, gs, vis):
    v = vis[..., None]
    return jnp.sum(jnp.where(v, g, 0.0), axis=1), jnp.sum(jnp.where(v, gs, 0.0), axis=1)


# --------------------------------------------------------------------------- geometry (view/env independent)

@dataclasses.dataclass
class Geometry:
    """Per-sample visibility for one method, computed once from the mesh
    (not differentiated) and reused across environments, rotations and
    frames: [P, D] booleans for "rig"/"dense", ambient occlusion and bent
    normals for "fast", a ray caster for "reference"."""

    vis: Any = None
    ao: Any = None
    bent: Any = None
    rays: Any = None
    mesh: Any = None       # lights: to cast the rotated lights' rays (an environment rotation moves them)
    surface: Any = None


def prepare_geometry(lt: Lighting, maps: MaterialMaps, surface: stage.Surface, mesh, visibility=None) -> Geometry:
    P = surface.num_samples
    g = Geometry()
    term = lt.settings["terminator"]
    if lt.method in ("rig", "dense", "lights"):
        D = lt.num_directions()
        if lt.method == "lights":
            g.mesh, g.surface = mesh, surface
        if visibility is not None:
            shp = visibility.shape if isinstance(visibility, stage.PackedMask) else np.shape(visibility)
            if tuple(shp) != (P, D):
                raise ValueError(f"visibility must be [P, D] = [{P}, {D}] for method {lt.method!r}, got {list(shp)}")
            g.vis = visibility
        elif mesh is not None:
            if lt.method == "rig":
                g.vis = stage.light_visibility(mesh, surface, lt.rig, packed=True, terminator=term)
            else:
                g.vis = stage.PackedMask.pack(direction_visibility(mesh, surface, np.asarray(lt.dirs), term))
        return g
    if visibility is not None:
        raise ValueError(f"method {lt.method!r} takes no visibility argument (it casts its own rays from mesh)")
    if lt.method == "fast":
        dt = lt.settings["dtype"]
        if mesh is None:
            g.ao = jnp.ones((P, 1), dt)
            g.bent = None
            return g
        dirs = brdf.fibonacci_sphere(lt.settings["ao_rays"], axis=1)
        vis = direction_visibility(mesh, surface, dirs, term)  # [P, K]
        n = np.asarray(maps.frame(surface).normal, np.float64)
        cos = np.maximum(n @ dirs.T, 0.0) * (np.asarray(surface.normal, np.float64) @ dirs.T > 0)  # [P, K]
        tot = cos.sum(1, keepdims=True)
        ok = tot > 0
        ao = np.where(ok, (cos * vis).sum(1, keepdims=True) / np.where(ok, tot, 1.0), 1.0)
        # Bent normal: n moved by the cosine-weighted mean of the unoccluded
        # directions minus that of all directions (so it is n exactly when
        # nothing is occluded, whatever the ray set's discretisation).
        m_vis = np.where(ok, (cos * vis) @ dirs / np.maximum((cos * vis).sum(1, keepdims=True), 1e-12), 0.0)
        m_all = np.where(ok, cos @ dirs / np.where(ok, tot, 1.0), 0.0)
        bent = n + np.where(ao > 0, m_vis - m_all, 0.0)
        bent /= np.maximum(np.linalg.norm(bent, axis=1, keepdims=True), 1e-12)
        g.ao = jnp.asarray(ao, dt)
        g.bent = jnp.asarray(bent, dt)
        return g
    if mesh is not None:
        g.rays = stage.Occluder(mesh, surface, term)
    return g


# --------------------------------------------------------------------------- shading

def _default_chunk(lt: Lighting) -> int:
    if lt.method in ("rig", "dense", "lights"):
        return _CHUNK_DIRECTIONAL
    if lt.method == "fast":
        return _CHUNK_FAST
    return max(16, _MC_PAIRS // min(lt.settings["samples"], _MC_PASS))


def _dir_call(n_dirs: int) -> int:
    """Directions per kernel call for a set of ``n_dirs``."""
    return _DIR_CALL if n_dirs >= _DIR_CALL else max(_DIR_BLOCK, 1 << (n_dirs - 1).bit_length())


def _pad_directions(light, strength, n_dirs):
    pad = (-n_dirs) % _dir_call(n_dirs)
    if pad:
        light = jnp.concatenate([light, jnp.repeat(light[-1:], pad, axis=0)])
        strength = jnp.concatenate([strength, jnp.zeros((pad,) + strength.shape[1:], strength.dtype)])
    return light, strength, pad


def shade(lt: Lighting, geo: Geometry, maps: MaterialMaps, surface: stage.Surface, wo, *, rotation=None, key=None,
          sss_exitance=None):
    """Radiance [P, C] toward ``wo`` [P, 3], and the radiant exitance M [P, C]
    of the subsurface term (None when no sample is SUBSURFACE).
    ``sss_exitance`` [P, C] (optional) is a precomputed M (render_view computes
    it in texel space, where the diffusion operator lives, and looks it up)."""
    s = lt.settings
    dt = s["dtype"]
    P = surface.num_samples
    fr = maps.frame(surface)
    m_all = (jnp.asarray(maps.rho_d, dt), jnp.asarray(maps.rho_s, dt), jnp.asarray(maps.alpha, dt),
             jnp.asarray(maps.model, jnp.int32), jnp.asarray(fr.tangent, dt), jnp.asarray(fr.bitangent, dt),
             jnp.asarray(fr.normal, dt))
    pos = jnp.asarray(surface.position, dt)
    ng = jnp.asarray(surface.normal, dt)
    wo = safe_normalize(jnp.asarray(wo, dt))
    model_np = _concrete(maps.model)
    if model_np is None and s["operator"] is None and sss_exitance is None:
        raise ValueError("maps.model is traced (under jit/grad): pass it as a concrete array, or pass operator= "
                         "so the subsurface term can be evaluated")
    has_sss = model_np is None or bool(np.any(model_np == SUBSURFACE))
    want_sss = has_sss and sss_exitance is None
    rot = jnp.eye(3, dtype=dt) if rotation is None else jnp.asarray(rotation, dt)
    # Chunks have a fixed shape (the last one padded by repeating the final
    # sample); P is rounded up to a power of two (>= 64) first, so that views
    # with different hit counts (orbit frames) share one compilation.
    chunk = min(s["chunk"] or _default_chunk(lt), max(64, 1 << (P - 1).bit_length()))
    n_chunks = -(-P // chunk)

    geo_vis = geo.vis
    if lt.method in ("rig", "dense", "lights"):
        light, strength, near = _strength(lt, rotation)
        D = light.shape[0]
        geo_vis = _light_visibility(lt, geo, light, rotation)
        light, strength, pad = _pad_directions(light, strength, D)
    elif lt.method == "fast":
        t_avg = jnp.asarray(fast.mean_transmittance(float(s["eta"])), dt)
    else:
        per_pass = min(s["samples"], _MC_PASS)
        passes = -(-s["samples"] // per_pass)
        n_env = int(round(per_pass * s["env_fraction"]))
        n_brdf = per_pass - n_env
        key = jax.random.PRNGKey(0) if key is None else key

    outs, es = [], []
    pad_idx = np.minimum(np.arange(n_chunks * chunk), P - 1)
    chunks = _Chunks(pad_idx, chunk, n_chunks, n_chunks * chunk != P, (pos, wo, ng))
    m_pad = tuple(chunks.padder(a) for a in m_all)
    for c in range(n_chunks):
        s0 = c * chunk
        n = min(chunk, P - s0)
        idx = pad_idx[s0:s0 + chunk]
        m = tuple(a[s0:s0 + chunk] for a in m_pad) if n_chunks > 1 else m_pad
        take = functools.partial(chunks.take, s0)
        if lt.method in ("rig", "dense", "lights"):
            if geo_vis is None:
                v = np.ones((chunk, D), bool)
            else:
                v = _rows(geo_vis, idx)
            if pad:
                v = np.concatenate([v, np.zeros((chunk, pad), bool)], axis=1)
            out = e = None
            call = _dir_call(D)
            for d0 in range(0, v.shape[1], call):
                d1 = d0 + call
                o, ee = _directional_kernel(m, take(pos), take(wo), light[d0:d1], strength[d0:d1],
                                            jnp.asarray(v[:, d0:d1]), float(s["eta"]), near, want_sss)
                out, e = (o, ee) if out is None else (out + o, e + ee)
        elif lt.method == "fast":
            bent = m[6] if geo.bent is None else take(geo.bent)
            out, e = _fast_kernel(m, take(wo), take(geo.ao), bent, rot, lt.sh, lt.levels, lt.lut, t_avg)
        else:
            out = e = None
            for p_ in range(passes):
                kp = jax.random.fold_in(jax.random.fold_in(key, c), p_)
                d, g, gs = _mc_sample(m, take(ng), take(wo), kp, rot, lt.sampler, lt.env.radiance,
                                      float(s["eta"]), n_env, n_brdf, s["heuristic"] == "power", want_sss,
                                      geo.rays is not None)
                if geo.rays is None:
                    vis = np.ones(d.shape[:2], bool)
                else:
                    active = np.asarray(jnp.any(g > 0, axis=-1) | jnp.any(gs > 0, axis=-1))
                    vis = geo.rays.visible(idx, np.asarray(d, np.float64), active)
                o, ee = _mc_sum(g, gs, jnp.asarray(vis))
                out, e = (o / passes, ee / passes) if out is None else (out + o / passes, e + ee / passes)
        outs.append(out[:n])
        es.append(e[:n])
    out = jnp.concatenate(outs) if len(outs) > 1 else outs[0]
    e_sss = jnp.concatenate(es) if len(es) > 1 else es[0]
    M = None
    if has_sss:
        is_sss = (m_all[3] == SUBSURFACE)[:, None]
        if sss_exitance is None:
            e_in = jnp.where(is_sss, e_sss, 0.0)
            op = s["operator"] if s["operator"] is not None else build_operator(maps, surface)
            M = op.apply(maps.profile(), e_in.astype(op.distance.dtype)).astype(dt)
        else:
            M = jnp.asarray(sss_exitance, dt)
        wo_l = stage.to_local(wo, m_all[4], m_all[5], m_all[6])
        seen = is_sss[:, 0] & (wo_l[:, 2] > 0)
        out = out + stage.subsurface_exitance(M, wo_l, float(s["eta"]), seen)
    return jnp.where(jnp.isfinite(out), out, 0.0), M


def _light_visibility(lt: Lighting, geo: Geometry, light, rotation):
    """The [P, D] visibility the directional kernel reads: the cached one, or
    for "lights" under a rotation (the lights moved with the environment) their
    shadows cast anew."""
    if lt.method == "lights" and rotation is not None:
        if geo.mesh is not None:
            return stage.PackedMask.pack(direction_visibility(geo.mesh, geo.surface, np.asarray(light, np.float64),
                                                              lt.settings["terminator"]))
        if geo.vis is not None:
            raise ValueError("method 'lights' with a rotation moves its lights: pass mesh= to cast their shadows "
                             "(a given visibility= holds the unrotated lights' shadows)")
    return geo.vis


class _Chunks:
    """Fixed-shape chunks of per-sample arrays: one gather pads an array to whole
    chunks (repeating the last sample), each chunk is then a static slice (a
    gather per array and chunk cost ~0.1 s per view in dispatch overhead).
    The arrays in ``cached`` are padded once."""

    def __init__(self, pad_idx, chunk, n_chunks, padded, cached):
        self.pad_idx, self.chunk, self.n_chunks, self.padded = pad_idx, chunk, n_chunks, padded
        self.cached = [(a, self.padder(a)) for a in cached]

    def padder(self, a):
        return a[self.pad_idx] if self.padded else a

    def take(self, s0, a):
        p = next((padded for orig, padded in self.cached if orig is a), None)
        p = self.padder(a) if p is None else p
        return p[s0:s0 + self.chunk] if self.n_chunks > 1 else p


def _concrete(x):
    try:
        return np.asarray(x)
    except Exception:  # a tracer (under jit/grad): treat the model map as unknown
        return None


# Energy fraction of the diffusion profile inside the operator's radius, and a
# cap on that radius in mean free paths (Burley profiles with tiny albedo
# would otherwise ask for huge neighbourhoods).
_SSS_ENERGY = 0.99


def build_operator(maps: MaterialMaps, surface: stage.Surface):
    """A ``skin_bssrdf.DiffusionOperator`` on the surface's samples whose radius
    holds 99% of the largest subsurface sample's profile energy."""
    import skin_bssrdf

    model = np.asarray(maps.model)
    sel = np.flatnonzero(model == SUBSURFACE)
    prof = maps.profile()
    r = np.asarray(skin_bssrdf.energy_radius(prof, _SSS_ENERGY))[sel]
    radius = float(np.max(r)) if r.size else 1.0
    radius = max(radius, 1e-3)
    return skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius)


def render_samples(maps: MaterialMaps, surface: stage.Surface, env: EnvMap, wo_world, *,
                   method: str | AbstractMethod = "rig",
                   mesh: stage.Mesh | None = None, rig: stage.Rig | None = None, visibility=None, key=None,
                   **settings) -> Float[Array, "sample 3"]:
    """Relit outgoing radiance [P, 3] at each surface sample toward ``wo_world``.

    Computes the direct reflection of the environment ``env`` (lat-long,
    radiance in its own units; the result is in the same units) off the
    material ``maps`` on ``surface`` (shading frame from the maps, see
    ``MaterialMaps.frame``), with shadows from ray casting against ``mesh``
    (None: no shadowing, every direction above the shading horizon is lit),
    plus, for samples with model == SUBSURFACE, Jensen et al. 2001's
    diffusion term (eq. 5) spread by a ``skin_bssrdf.DiffusionOperator``
    (see the module docstring of ``relight.render`` for the equations).

    Args:
        maps: ``relight.MaterialMaps`` over the surface's P samples.
        surface: ``stage.Surface`` (positions in mm; its interpolated
            normals give the horizon test; shadow rays leave along the mesh's
            face normals, see ``stage.Occluder``).
        env: ``relight.envmap.EnvMap``.
        wo_world: [P, 3] or [3] unit directions toward the viewer (world).
        method: a method object (``relight.render.Rig``, ``Dense``, ``Fast``,
            ``Reference``, ``Lights``, holding that method's settings) or one of
            the string names ``METHODS`` = ("rig", "dense", "fast", "reference", "lights"),
            which take the method's settings as keyword arguments (below).
        mesh: ``stage.Mesh`` for shadows (visibility is computed once here;
            pass ``visibility`` to reuse it).
        rig: the rig of method "rig" (default ``stage.light_stage_x()``).
        visibility: precomputed bool [P, D] or ``stage.PackedMask`` for
            "rig" (D = lights, ``stage.light_visibility``) or "dense" (D =
            2 resolution^2 lat-long pixel directions, row-major).
        key: ``jax.random`` key of method "reference" (default PRNGKey(0)).

    Settings (keyword arguments):
        all methods: ``chunk`` samples per step (bounded memory; default 4096
        for rig/dense, 16384 for fast, 2^18 / samples for reference);
        ``eta`` = 1.4 relative index for the subsurface Fresnel
        transmittances; ``operator`` a prebuilt ``DiffusionOperator`` on the
        same samples (default: built with the radius holding 99% of the
        profile energy); ``rotation`` a 3x3 rotation of the environment (light
        that arrived from d arrives from R d; exact for every method, no
        resampling, except "dense" at rotations other than whole pixels about
        y); ``dtype`` (float32); ``terminator`` (True) shadow rays from the
        smooth surface the interpolated normals describe (Hanika 2021, see
        ``stage.Occluder``), False from the flat facets (as Mitsuba 3 and
        pbrt-v4 cast them, for like-for-like comparisons).
        "rig": ``weights`` "voronoi" (default, ``light_weights``) or
        "barycentric"; ``supersample`` (1) of the weights.
        "dense": ``resolution`` (32) rows of the lat-long quadrature grid
        (2 resolution^2 distant lights, each the area mean of the map).
        "lights": ``lights`` (256) median-cut regions of equal energy, each a
        distant light (``visibility`` then has D = lights columns, in the
        order of ``relight.render._lights.median_cut``).
        "fast": ``levels`` (7) prefiltered roughness levels,
        ``prefilter_rows`` (128), ``prefilter_samples`` (64) GGX samples
        per prefiltered texel, ``ao_rays`` (64) visibility rays per sample for
        ambient occlusion and bent normals, ``lut_size`` (32) of the DFG table.
        "reference": ``samples`` (256) directions per sample (run in passes
        of 64, so rounded up to a multiple of 64 above 64),
        ``env_fraction`` (0.5) of them from environment sampling, the rest
        from BRDF sampling; ``heuristic`` "power" (default, beta = 2) or
        "balance" (Veach & Guibas 1995, eq. 9 and 12).

    Returns radiance [P, 3] (float32 by default), never NaN or Inf. Raises
    ValueError on an unknown method or setting, inputs of the wrong type or
    shape, or maps and surface of different sizes.
    """
    if rig is not None:
        name = method.name if isinstance(method, AbstractMethod) else method
        if name != "rig":
            raise ValueError(f"rig= is a setting of method 'rig', not of {name!r}")
        if isinstance(method, AbstractMethod):
            raise ValueError("rig= with a method object: give it as relight.render.Rig(rig=...)")
        settings["rig"] = rig
    s = _settings(method, settings)
    wo = check_inputs(maps, surface, env, wo_world)
    if mesh is not None and not isinstance(mesh, stage.Mesh):
        raise ValueError(f"mesh must be a stage.Mesh or None, got {type(mesh).__name__}")
    lt = prepare_lighting(env, s["method"].name, s)
    geo = prepare_geometry(lt, maps, surface, mesh, visibility)
    out, _ = shade(lt, geo, maps, surface, wo, rotation=s["rotation"], key=key)
    return out
