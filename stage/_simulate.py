"""OLAT capture simulation: every light of a rig, one at a time, on every
surface sample, as every camera sees it.

Surface reflection: L_o(p, wo) = f_r(wi, wo) cos(theta_i) E_l(p) V_l(p) for
light l, with E_l the irradiance at normal incidence (inverse-square for
near-field lights) and V_l the ray-cast visibility (the reflection equation for
a point source, pbrt-v4 eq. 4.14 with a delta light).

Subsurface (optional, ``Subsurface``): Jensen et al. 2001's diffusion BSSRDF
S_d = (1/pi) F_t(eta, wi) R_d(|x_i - x_o|) F_t(eta, wo) (their eq. 5)
integrated over the surface by skin_bssrdf's ``DiffusionOperator``:
L_ss(x_o, wo) = F_t(eta, cos_o) / pi * sum_j w_oj F_t(eta, cos_i,j) cos_i,j E_l,j V_l,j.

Polarisation (optional): an ideal linear polariser on every light and an
analyser on the camera. Single-surface (specular) reflection keeps the
polarisation: the parallel analyser passes it, the crossed one blocks it.
Diffuse and subsurface light leaves depolarised: either analyser passes half.
So parallel - cross = specular and 2 x cross = diffuse (Ma et al. 2007, sec. 4).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import brdf
from brdf import safe_normalize

from ._camera import Camera
from ._capture import Capture
from ._rig import Rig
from ._surface import Surface
from ._visibility import PackedMask, as_mask

# Fraction of depolarised light an ideal linear analyser transmits (Malus's law
# averaged over polarisation angles).
DEPOLARIZED_TRANSMISSION = 0.5


def shading_directions(surface: Surface, rig: Rig, camera_center):
    """Local-frame wi [L, P, 3], wo [P, 3] and irradiance at normal incidence [L, P, C].

    ``camera_center``: the camera's centre [3] (mm), or a ``Camera`` (needed for
    an orthographic one, whose wo is the same everywhere)."""
    wi_world, irradiance = rig.incident(surface.position)
    if isinstance(camera_center, Camera):
        wo_world = camera_center.view_directions(surface.position)
    else:
        wo_world = safe_normalize(jnp.asarray(camera_center)[None, :] - surface.position)
    return surface.to_local(wi_world), surface.to_local(wo_world), irradiance


class Subsurface(eqx.Module):
    """Subsurface scattering for ``simulate``: a skin_bssrdf ``profile``
    (parameters [C] or [P, C]), the ``operator`` (skin_bssrdf.DiffusionOperator
    built on the same samples) and the relative index of refraction ``eta``
    (skin: 1.4) for the Fresnel transmittances in and out."""

    profile: eqx.Module
    operator: eqx.Module
    eta: float = 1.4


def split_material(material):
    """(diffuse, specular) parts of a brdf model: the ``brdf.Lambert`` terms of a
    ``brdf.Sum`` are diffuse (depolarising), every other term specular. Either
    part is None when empty."""
    if isinstance(material, brdf.Sum):
        d = [t for t in material.terms if isinstance(t, brdf.Lambert)]
        s = [t for t in material.terms if not isinstance(t, brdf.Lambert)]
        mk = lambda ts: None if not ts else (ts[0] if len(ts) == 1 else brdf.Sum(*ts))  # noqa: E731
        return mk(d), mk(s)
    if isinstance(material, brdf.Lambert):
        return material, None
    return None, material


def _shade(material: "brdf.AbstractBRDF", wi, wo, irradiance, visible):
    """radiance [Lc, P, C] = f(wi, wo) cos_i E V for a chunk of lights (vmap over lights)."""

    def one_light(wi_l, e_l, v_l):
        f = material(wi_l, wo)
        cos_i = jnp.maximum(wi_l[..., 2:3], 0)
        return jnp.where(v_l[:, None], f * cos_i * e_l, 0)

    return jax.vmap(one_light)(wi, irradiance, visible)


_shade_chunk = eqx.filter_jit(_shade)


def _transmittance(cos, eta):
    return 1.0 - brdf.fresnel_dielectric(jnp.clip(cos, 0.0, 1.0), eta)


def _subsurface(sss: Subsurface, wi, wo, irradiance, lit, seen):
    """L_ss [Lc, P, C]: Jensen 2001 eq. 5 through the diffusion operator."""
    cos_i = jnp.maximum(wi[..., 2:3], 0)
    e_in = jnp.where(lit[..., None], _transmittance(cos_i, sss.eta) * cos_i * irradiance, 0)
    m = jax.vmap(lambda e: sss.operator.apply(sss.profile, e))(e_in)
    t_out = _transmittance(jnp.maximum(wo[:, 2:3], 0), sss.eta)[None]
    return jnp.where(seen[None, :, None], t_out / jnp.pi * m, 0)


@eqx.filter_jit
def _fused_chunk(terms, subsurface, sss_weight, rig_chunk: Rig, surface: Surface, wo_world, light_vis, seen):
    """One (light chunk x sample chunk) block in one XLA computation: incident
    directions and irradiance, the change to the shading frame, every reflection
    term and the subsurface term. ``light_vis`` [Lc, Pc] (ray-cast), ``seen``
    [Pc] (camera). Returns (radiance [Lc, Pc, C], lit [Lc, Pc]: cos_i > 0)."""
    wi_world, irr = rig_chunk.incident(surface.position)
    wi = surface.to_local(wi_world)
    wo = surface.to_local(wo_world)
    out = None
    visible = light_vis & seen[None]
    for m, wgt in terms:
        r = _shade(m, wi, wo, irr, visible) * wgt
        out = r if out is None else out + r
    if subsurface is not None:
        r = _subsurface(subsurface, wi, wo, irr, light_vis, seen) * sss_weight
        out = r if out is None else out + r
    if out is None:  # cross-polarised pure specular: nothing reaches the sensor
        out = jnp.zeros(irr.shape, jnp.float32)
    return out, wi[..., 2] > 0


def _take_samples(tree, P: int, idx):
    """Rows ``idx`` of every array leaf whose leading axis is the sample axis (length P)."""
    return jax.tree_util.tree_map(
        lambda x: x[idx] if hasattr(x, "ndim") and x.ndim >= 1 and x.shape[0] == P else x, tree)


def _chunks(surface, rig, cameras, terms, sss_weight, subsurface, light_visibility, cv, light_chunk, sample_chunk,
            progress):
    """Yield (view, light slice, sample slice, radiance [Lc, Pc, C], mask [Lc, Pc])."""
    P, L = surface.num_samples, rig.num_lights
    # Weights as arrays: traced, so captures differing only in them share a compilation.
    terms = [(m, jnp.asarray(w, jnp.float32)) for m, w in terms]
    sss_weight = jnp.asarray(sss_weight, jnp.float32)
    for v, cam in enumerate(cameras):
        z = np.asarray(cam.to_camera(surface.position))[:, 2]
        if not np.any(z > 0):
            raise ValueError(f"camera {v} at {np.round(np.asarray(cam.center), 1).tolist()} has every surface sample "
                             "behind it (check its R, t: it looks away from the surface)")
        for ps0 in range(0, P, sample_chunk):
            ps1 = min(ps0 + sample_chunk, P)
            n_s = ps1 - ps0
            if sample_chunk >= P:
                idx, sub, sub_terms = None, surface, terms
            else:
                # Every sample chunk has the same shape (the last one padded by
                # repeating its final sample), so the kernels compile once.
                idx = np.minimum(np.arange(ps0, ps0 + sample_chunk), ps1 - 1)
                sub = surface.subset(idx)
                sub_terms = [(_take_samples(m, P, idx), w) for m, w in terms]
            wo_world = cam.view_directions(sub.position)
            front = np.asarray(sub.to_local(wo_world)[:, 2] > 0) & (cv[v] if idx is None else cv[v, idx])
            front_j = jnp.asarray(front)
            if idx is None:
                lv_rows = light_visibility
            elif isinstance(light_visibility, PackedMask):
                lv_rows = PackedMask(light_visibility.bits[idx], light_visibility.n)
            else:
                lv_rows = light_visibility[idx]
            for s in range(0, L, light_chunk):
                e = min(s + light_chunk, L)
                lv_c = as_mask(lv_rows, s, e).T  # [Lc, Pc]
                # Pad the last light chunk to the chunk size (repeat a light, invisible): one compilation.
                pad = light_chunk - (e - s) if L > light_chunk else 0
                li = np.minimum(np.arange(s, e + pad), e - 1)
                rig_c = Rig(position=rig.position[li], intensity=rig.intensity[li], solid_angle=rig.solid_angle[li],
                            near_field=rig.near_field)
                lv_p = np.zeros((e - s + pad, lv_c.shape[1]), bool)
                lv_p[: e - s] = lv_c
                out, lit = _fused_chunk(sub_terms, subsurface, sss_weight, rig_c, sub, wo_world, jnp.asarray(lv_p), front_j)
                out = out[: e - s, :n_s]
                msk = (lv_c & front[None] & np.asarray(lit)[: e - s])[:, :n_s]
                yield v, slice(s, e), slice(ps0, ps1), out, msk
                if progress is not None:
                    progress(e - s)


def _prepare(surface, rig, cameras, material, light_visibility, camera_visibility, polarization, subsurface):
    cameras = tuple(cameras) if isinstance(cameras, (list, tuple)) else (cameras,)
    if not all(isinstance(c, Camera) for c in cameras) or not cameras:
        raise ValueError("simulate needs at least one stage.Camera")
    if polarization not in (None, "parallel", "cross"):
        raise ValueError(f"polarization must be None, 'parallel' or 'cross', got {polarization!r}")
    if subsurface is not None and not isinstance(subsurface, Subsurface):
        raise ValueError("subsurface must be a stage.Subsurface(profile, operator, eta)")
    if subsurface is not None and subsurface.operator.num_samples != surface.num_samples:
        raise ValueError(f"subsurface operator has {subsurface.operator.num_samples} samples, surface has {surface.num_samples}")
    P, L = surface.num_samples, rig.num_lights
    if isinstance(light_visibility, PackedMask):
        lv_shape = light_visibility.shape
    else:
        light_visibility = np.asarray(light_visibility, dtype=bool)
        lv_shape = light_visibility.shape
    cv = np.asarray(camera_visibility, dtype=bool)
    if lv_shape != (P, L):
        raise ValueError(f"light_visibility must have shape [P, L] = {(P, L)}, got {lv_shape}")
    if cv.shape != (len(cameras), P):
        raise ValueError(f"camera_visibility must have shape [V, P] = {(len(cameras), P)}, got {cv.shape}")
    terms = []
    if polarization is None:
        if material is not None:
            terms.append((material, 1.0))
        sss_weight = 1.0
    else:
        diffuse, specular = split_material(material) if material is not None else (None, None)
        if diffuse is not None:
            terms.append((diffuse, DEPOLARIZED_TRANSMISSION))
        if specular is not None and polarization == "parallel":
            terms.append((specular, 1.0))
        sss_weight = DEPOLARIZED_TRANSMISSION
    if subsurface is None and material is None:
        raise ValueError("simulate needs a material or a subsurface model")
    return cameras, light_visibility, cv, terms, sss_weight


def simulate_chunks(surface: Surface, rig: Rig, cameras, material: "brdf.AbstractBRDF", light_visibility,
                    camera_visibility, *, light_chunk: int = 64, sample_chunk: int = 1 << 16, progress=None,
                    polarization: str | None = None, subsurface: Subsurface | None = None):
    """``simulate`` as a stream: yields (view, light slice, sample slice,
    radiance [Lc, Pc, C] (a JAX array), mask [Lc, Pc] (NumPy bool)) one chunk at a
    time, so peak memory is one chunk (light_chunk x sample_chunk x C floats plus
    the per-chunk shading temporaries), not the capture. Arguments as ``simulate``;
    with ``subsurface`` the sample axis is not chunked (the operator couples samples)."""
    cameras, lv, cv, terms, sss_weight = _prepare(surface, rig, cameras, material, light_visibility,
                                                  camera_visibility, polarization, subsurface)
    P = surface.num_samples
    sample_chunk = P if subsurface is not None else max(1, int(sample_chunk))
    yield from _chunks(surface, rig, cameras, terms, sss_weight, subsurface, lv, cv, int(light_chunk), sample_chunk,
                       progress)


def simulate(surface: Surface, rig: Rig, cameras, material: "brdf.AbstractBRDF", light_visibility,
             camera_visibility, *, light_chunk: int = 64, dtype=jnp.float32, progress=None,
             polarization: str | None = None, subsurface: Subsurface | None = None) -> Capture:
    """Simulate an OLAT capture of ``material`` (a brdf Module whose parameters
    have a leading sample axis [P, ...], or none) on ``surface`` under ``rig``.

    light_visibility: bool [P, L] or a ``PackedMask`` (stage.light_visibility);
    camera_visibility: bool [V, P] (stage.camera_visibility). Returns a Capture
    whose radiance is 0 where the light is shadowed, and whose mask marks the
    observations that are lit, seen and front-facing. ``progress(n)`` is called
    after each light chunk. Peak memory beyond the output is one light chunk:
    light_chunk x P x C floats (plus the operator's chunk for subsurface).

    polarization: None (no filters), "parallel" or "cross" (see the module
    docstring; the material is split by ``split_material``). subsurface: a
    ``Subsurface``; then ``material`` should hold only the surface (specular)
    reflection, since the diffuse part comes from the diffusion operator.
    Raises ValueError on mismatched shapes or a camera with every sample
    behind it.
    """
    cameras, light_visibility, cv, terms, sss_weight = _prepare(surface, rig, cameras, material, light_visibility,
                                                                camera_visibility, polarization, subsurface)
    P, L = surface.num_samples, rig.num_lights
    radiance = None
    mask = np.zeros((len(cameras), L, P), bool)
    for v, ls, ps, rad, msk in _chunks(surface, rig, cameras, terms, sss_weight, subsurface, light_visibility, cv,
                                       light_chunk, P, progress):
        if radiance is None:
            radiance = np.zeros((len(cameras), L, P, rad.shape[-1]), dtype)
        radiance[v, ls, ps] = np.asarray(rad).astype(dtype)
        mask[v, ls, ps] = msk
    return Capture(radiance=jnp.asarray(radiance), mask=jnp.asarray(mask), rig=rig, cameras=cameras)
