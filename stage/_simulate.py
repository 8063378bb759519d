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

The physics is ``stage._forward`` (``incident_light``, ``to_local``,
``reflected_radiance``, ``subsurface_irradiance``, ``subsurface_exitance``);
this module only schedules it in (light x sample) chunks and applies the
visibility and the polariser weights. Everything but the ray-cast visibility
is traced, so ``jax.grad`` goes through ``simulate``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import brdf
from brdf import safe_normalize
from skin_bssrdf import SKIN_ETA

from ._camera import Camera
from ._capture import Capture
from ._forward import (
    _traced,
    as_float,
    reflected_radiance_lights,
    subsurface_exitance,
    subsurface_irradiance,
    widest_float,
)
from ._progress import Phase
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
    if not isinstance(camera_center, Camera):
        camera_center = jnp.asarray(camera_center)
    return _shading_directions(surface, rig, camera_center)


@eqx.filter_jit
def _shading_directions(surface: Surface, rig: Rig, camera_center):
    """:func:`shading_directions` as one program (eager, its operations would each compile on their own for
    every new sample count)."""
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
    (default: skin's, ``skin_bssrdf.SKIN_ETA``) for the Fresnel transmittances in and out."""

    profile: eqx.Module
    operator: eqx.Module
    eta: float = SKIN_ETA


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


def _subsurface(sss: Subsurface, wi, wo, irradiance, lit, seen):
    """L_ss [Lc, P, C]: Jensen 2001 eq. 5 through the diffusion operator
    (``stage.subsurface_irradiance``, the operator, ``stage.subsurface_exitance``)."""
    e_in = subsurface_irradiance(wi, irradiance, sss.eta, lit)
    # The operator computes in its own dtype (its distances'); the capture stays in the irradiance's.
    op_dt = sss.operator.distance.dtype
    m = jax.vmap(lambda e: sss.operator.apply(sss.profile, e.astype(op_dt)).astype(e.dtype))(e_in)
    return subsurface_exitance(m, wo[None], sss.eta, seen[None])


@eqx.filter_jit
def _fused_chunk(terms, subsurface, sss_weight, rig_chunk: Rig, surface: Surface, wo_world, light_vis, cam_vis):
    """One (light chunk x sample chunk) block in one XLA computation: incident
    directions and irradiance, the change to the shading frame, every reflection
    term and the subsurface term. ``light_vis`` [Lc, Pc] (ray-cast), ``cam_vis``
    [Pc] (camera, ray-cast). Returns (radiance [Lc, Pc, C], mask [Lc, Pc]: lit,
    seen and front-facing, cos_i > 0 and cos_o > 0)."""
    wi_world, irr = rig_chunk.incident(surface.position)
    wi = surface.to_local(wi_world)
    wo = surface.to_local(wo_world)
    seen = cam_vis & (wo[:, 2] > 0)
    out = None
    visible = light_vis & seen[None]
    for m, wgt in terms:
        r = reflected_radiance_lights(m, wi, wo, irr, visible) * wgt.astype(irr.dtype)
        out = r if out is None else out + r
    if subsurface is not None:
        r = _subsurface(subsurface, wi, wo, irr, light_vis, seen) * sss_weight.astype(irr.dtype)
        out = r if out is None else out + r
    if out is None:  # cross-polarised pure specular: nothing reaches the sensor
        out = jnp.zeros(irr.shape, irr.dtype)
    return out, visible & (wi[..., 2] > 0)


def _take_samples(tree, P: int, idx):
    """Rows ``idx`` of every array leaf whose leading axis is the sample axis
    (length P); a BRDF whose arrays are shared by every sample
    (``per_sample = False``: MERL, NBRDF) is kept whole."""
    shared = lambda x: isinstance(x, brdf.AbstractBRDF) and not x.per_sample  # noqa: E731
    return jax.tree_util.tree_map(
        lambda x: x if shared(x) else (x[idx] if hasattr(x, "ndim") and x.ndim >= 1 and x.shape[0] == P else x),
        tree, is_leaf=shared)


def _check_in_front(v: int, cam: Camera, positions) -> None:
    """ValueError when camera ``v`` has every sample behind it; skipped when the
    camera or the positions are traced (the check needs concrete values)."""
    z = cam.to_camera(positions)[:, 2]
    if _traced(z):
        return
    if not np.any(np.asarray(z) > 0):
        raise ValueError(f"camera {v} at {np.round(np.asarray(cam.center), 1).tolist()} has every surface sample "
                         "behind it (check its R, t: it looks away from the surface)")


def _chunks(surface, rig, cameras, terms, sss_weight, subsurface, light_visibility, cv, light_chunk, sample_chunk,
            progress):
    """Yield (view, light slice, sample slice, radiance [Lc, Pc, C], mask [Lc, Pc])
    as JAX arrays. Only the chunk schedule and the precomputed (ray-cast,
    concrete) visibility live on the host; everything that depends on the
    material, the surface, the rig or the camera is JAX, so the chunks can be
    traced (jax.grad / jax.jvp through ``simulate``)."""
    P, L = surface.num_samples, rig.num_lights
    # Weights as arrays: traced, so captures differing only in them share a compilation.
    terms = [(m, jnp.asarray(w, jnp.float32)) for m, w in terms]
    sss_weight = jnp.asarray(sss_weight, jnp.float32)
    bar = Phase(progress, "simulate", len(cameras) * -(-P // sample_chunk) * L)
    # The light chunks (padded to the chunk size by repeating a light: one
    # compilation) are the same for every view and sample chunk: gather them once.
    light_chunks = []
    for s in range(0, L, light_chunk):
        e = min(s + light_chunk, L)
        pad = light_chunk - (e - s) if L > light_chunk else 0
        li = np.minimum(np.arange(s, e + pad), e - 1)
        light_chunks.append((s, e, pad, Rig(position=rig.position[li], intensity=rig.intensity[li],
                                            solid_angle=rig.solid_angle[li], near_field=rig.near_field)))
    for v, cam in enumerate(cameras):
        _check_in_front(v, cam, surface.position)
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
            cv_j = jnp.asarray(cv[v] if idx is None else cv[v, idx])
            if idx is None:
                lv_rows = light_visibility
            elif isinstance(light_visibility, PackedMask):
                lv_rows = PackedMask(light_visibility.bits[idx], light_visibility.n)
            else:
                lv_rows = light_visibility[idx]
            for s, e, pad, rig_c in light_chunks:
                lv_c = as_mask(lv_rows, s, e).T  # [Lc, Pc]; the padding lights are invisible
                lv_p = np.zeros((e - s + pad, lv_c.shape[1]), bool)
                lv_p[: e - s] = lv_c
                out, msk = _fused_chunk(sub_terms, subsurface, sss_weight, rig_c, sub, wo_world, jnp.asarray(lv_p),
                                        cv_j)
                yield v, slice(s, e), slice(ps0, ps1), out[: e - s, :n_s], msk[: e - s, :n_s]
                bar.advance(e - s)


def _prepare(surface, rig, cameras, material, light_visibility, camera_visibility, polarization, subsurface):
    cameras = tuple(cameras) if isinstance(cameras, (list, tuple)) else (cameras,)
    if not all(isinstance(c, Camera) for c in cameras) or not cameras:
        raise ValueError("simulate needs at least one stage.Camera")
    if polarization not in (None, "parallel", "cross"):
        raise ValueError(f"polarization must be None, 'parallel' or 'cross', got {polarization!r}")
    if subsurface is not None and not isinstance(subsurface, Subsurface):
        raise ValueError("subsurface must be a stage.Subsurface(profile, operator, eta)")
    if subsurface is not None and subsurface.operator.num_samples != surface.num_samples:
        raise ValueError(f"subsurface operator has {subsurface.operator.num_samples} samples, "
                         f"surface has {surface.num_samples}")
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


def simulate_chunks(surface: Surface, rig: Rig, cameras, material: brdf.AbstractBRDF | None, light_visibility,
                    camera_visibility, *, light_chunk: int = 64, sample_chunk: int = 1 << 16, progress=None,
                    polarization: str | None = None, subsurface: Subsurface | None = None):
    """``simulate`` as a stream: yields (view, light slice, sample slice,
    radiance [Lc, Pc, C] (a JAX array), mask [Lc, Pc] (NumPy bool; JAX when traced)) one chunk at a
    time, so peak memory is one chunk (light_chunk x sample_chunk x C floats plus
    the per-chunk shading temporaries), not the capture. Arguments as ``simulate``;
    with ``subsurface`` the sample axis is not chunked (the operator couples samples)."""
    cameras, lv, cv, terms, sss_weight = _prepare(surface, rig, cameras, material, light_visibility,
                                                  camera_visibility, polarization, subsurface)
    P = surface.num_samples
    sample_chunk = P if subsurface is not None else max(1, int(sample_chunk))
    for v, ls, ps, rad, msk in _chunks(surface, rig, cameras, terms, sss_weight, subsurface, lv, cv, int(light_chunk),
                                       sample_chunk, progress):
        yield v, ls, ps, rad, (msk if _traced(msk) else np.asarray(msk))


def simulate(surface: Surface, rig: Rig, cameras, material: brdf.AbstractBRDF | None, light_visibility,
             camera_visibility, *, light_chunk: int = 64, dtype=None, progress=None,
             polarization: str | None = None, subsurface: Subsurface | None = None) -> Capture:
    """Simulate an OLAT capture of ``material`` (a brdf Module whose parameters
    have a leading sample axis [P, ...], or none) on ``surface`` under ``rig``.

    light_visibility: bool [P, L] or a ``PackedMask`` (stage.light_visibility);
    camera_visibility: bool [V, P] (stage.camera_visibility). Returns a Capture
    whose radiance is 0 where the light is shadowed, and whose mask marks the
    observations that are lit, seen and front-facing. ``progress(phase, done,
    total)`` (``stage.Progress``) counts (view, light) images done, per sample
    chunk. Peak memory beyond the output is one light chunk:
    light_chunk x P x C floats (plus the operator's chunk for subsurface).

    polarization: None (no filters), "parallel" or "cross" (see the module
    docstring; the material is split by ``split_material``). subsurface: a
    ``Subsurface``; then ``material`` should hold only the surface (specular)
    reflection, since the diffuse part comes from the diffusion operator.
    Raises ValueError on mismatched shapes or a camera with every sample
    behind it (checked only when the camera and positions are concrete).

    dtype: the radiance's dtype; None (default): the widest floating dtype of
    the inputs (material, surface, rig, cameras, subsurface), so float64
    material maps under ``jax_enable_x64`` give a float64 capture, never a
    silently narrowed one.

    Differentiable: under ``jax.grad`` / ``jax.jvp`` / ``jax.jit`` the capture's
    radiance is a function of the material's parameters (the brdf Module's
    leaves), the surface's positions and shading frame, the rig's positions
    and intensities, the cameras' R and t and the subsurface profile; the
    visibility inputs are concrete and not differentiated (a shadow or
    front-facing boundary moves with no derivative). Traced calls assemble
    the capture with jnp (the output is held twice for a moment); concrete
    calls fill a host buffer.
    """
    cameras, light_visibility, cv, terms, sss_weight = _prepare(surface, rig, cameras, material, light_visibility,
                                                                camera_visibility, polarization, subsurface)
    # One float policy: the geometry, rig and cameras compute in the material's dtype where it is wider (the
    # brdf kernels evaluate in their directions' dtype), and the radiance keeps it unless dtype says otherwise.
    # The capture records the rig and cameras as given.
    wide = widest_float(material, surface, rig, cameras, subsurface)
    surface_w, rig_w, cameras_w, terms = as_float((surface, rig, cameras, terms), wide)
    dtype = wide if dtype is None else jnp.dtype(dtype)
    P, L = surface.num_samples, rig.num_lights
    chunks = _chunks(surface_w, rig_w, cameras_w, terms, sss_weight, subsurface, light_visibility, cv,
                     int(light_chunk), P, progress)
    if _traced(surface, rig, cameras, material, subsurface):
        # Under a transformation: assemble with jnp (JAX owns the buffers, the
        # capture is differentiable). The sample axis is not chunked here, so
        # each view is its light chunks in order.
        views_r, views_m = [[] for _ in cameras], [[] for _ in cameras]
        for v, _, _, rad, msk in chunks:
            views_r[v].append(rad.astype(dtype))
            views_m[v].append(msk)
        radiance = jnp.stack([jnp.concatenate(r, axis=0) for r in views_r])
        mask = jnp.stack([jnp.concatenate(m, axis=0) for m in views_m])
        return Capture(radiance=radiance, mask=mask, rig=rig, cameras=cameras)
    # Concrete: fill a host buffer chunk by chunk, so the peak beyond the
    # output is one chunk (a concatenation would hold the capture twice).
    radiance = None
    mask = np.zeros((len(cameras), L, P), bool)
    for v, ls, ps, rad, msk in chunks:
        if radiance is None:
            radiance = np.zeros((len(cameras), L, P, rad.shape[-1]), dtype)
        radiance[v, ls, ps] = np.asarray(rad.astype(dtype))
        mask[v, ls, ps] = np.asarray(msk)
    return Capture(radiance=jnp.asarray(radiance), mask=jnp.asarray(mask), rig=rig, cameras=cameras)
