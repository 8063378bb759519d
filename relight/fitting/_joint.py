"""BRDF and subsurface together: alternate the specular lobe and the
diffusion term so that neither absorbs the other.

A BRDF fit of subsurface-scattering data explains the light that diffusion
carries across the shading terminator (and toward grazing lights) with a
broad specular lobe: F0 several times too high, the diffuse albedo too low
(measured on the textured head: F0 median error 29%, 95th percentile ~10x).
:func:`relight.fit_subsurface` keeps that lobe, so the bias stays. Here, as
in block-coordinate descent on the joint least-squares problem (each block
solved exactly by its own solver):

1. ``relight.fit`` (the BRDF ladder, optionally normals) on the capture;
2. ``relight.fit_subsurface`` on it (the lobe and normals held);
3. ``passes - 1`` times: the lobe refitted by ``relight.fit`` on the capture
   minus the subsurface radiance the current maps predict
   (:func:`subsurface_radiance`: Jensen et al. 2001 eq. 5 through the same
   diffusion operator; for every sample, those the ladder left without
   subsurface taking their region's mean free path and a Lambert-only fit's
   albedo, so the lobe does not depend on that choice), in the first pass's
   shading frame (the normals come
   from the shading of the whole signal, which the subtraction would weaken);
   then ``fit_subsurface`` again with that lobe.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

import skin_bssrdf
import stage

from ..materials._maps import SUBSURFACE
from ._driver import fit
from ._options import FitOptions, as_options
from ._result import Fit
from ._subsurface import default_radius_mm, fit_subsurface


def subsurface_radiance(capture: stage.Capture, surface: stage.Surface, fitted: Fit, *, eta: float = 1.4,
                        radius_mm: float = 8.0) -> np.ndarray:
    """The subsurface radiance [V, L, P, C] (capture units) that ``fitted``'s
    maps predict for each observation: Jensen et al. 2001 eq. 5,
    ``stage.subsurface_irradiance`` -> the diffusion operator with each
    sample's Christensen-Burley profile (albedo rho_d, mean free path mfp) ->
    ``stage.subsurface_exitance``, in the fitted shading frame; 0 for samples
    that are not on the subsurface rung. A light counts as reaching a sample
    where any view has a valid observation of it (as the fitter's irradiance)."""
    V, L, P, C = capture.radiance.shape
    out = np.zeros((V, L, P, C), np.float32)
    if fitted.mfp is None or not np.any(np.asarray(fitted.model) == SUBSURFACE):
        return out
    maps = fitted.maps(surface)
    fr = maps.frame(surface)
    op = skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius_mm)
    on = np.asarray(maps.model) == SUBSURFACE
    prof = maps.profile()
    lit = jnp.asarray(np.any(np.asarray(capture.mask), axis=0))  # [L, P]
    wi, _, irr = stage.shading_directions(fr, capture.rig, capture.cameras[0])
    e_in = stage.subsurface_irradiance(wi, irr, eta, lit)  # [L, P, C]
    # The diffused exitance does not depend on the view: once per light (sequential: memory of one light).
    m = jax.lax.map(lambda e: op.apply(prof, e), e_in)
    for v, cam in enumerate(capture.cameras):
        wo = stage.shading_directions(fr, capture.rig, cam)[1]
        out[v] = np.asarray(stage.subsurface_exitance(m.astype(wo.dtype), wo[None], eta), np.float32)
    out[:, :, ~on] = 0.0
    return out


def _everywhere(out: Fit, labels: np.ndarray, rho_fill) -> Fit:
    """``out`` with every sample on the subsurface rung: those without one get
    the median mean free path of their region's subsurface samples (of all
    subsurface samples where their region has none; none at all: unchanged)
    and the albedo ``rho_fill`` (a Lambert-only fit's: a lobe cannot take
    their diffused light there)."""
    model = np.asarray(out.model)
    on = model == SUBSURFACE
    if out.mfp is None or not on.any():
        return out
    mfp = np.asarray(out.mfp).copy()
    fill = np.median(mfp[on], axis=0)
    for r in np.unique(labels[~on]):
        sel = labels == r
        mfp[sel & ~on] = np.median(mfp[sel & on], axis=0) if np.any(sel & on) else fill
    rho = np.where(on[:, None], np.asarray(out.rho_d), np.asarray(rho_fill))
    return dataclasses.replace(out, mfp=jnp.asarray(mfp, out.mfp.dtype), rho_d=jnp.asarray(rho, out.rho_d.dtype),
                               model=jnp.full_like(out.model, SUBSURFACE))


# The BRDF fits' loss when subsurface is fitted too (unless fit_options say otherwise). Before the subsurface is
# modelled, the local model meets light that diffused across shadow terminators and texel boundaries: heavy-tailed
# model error that L2 (relight.fit's default) fits as data. Measured on the demo's 32^2 head (tests/relight/
# test_cli.py::test_demo_end_to_end): median albedo error 3.0% with the Cauchy loss, 9.9% with L2 (docs/fit.md,
# "Defaults").
SUBSURFACE_LOSS = "cauchy"


def fit_with_subsurface(capture: stage.Capture, surface: stage.Surface, *, model: str = "auto", normals: bool = True,
                        per: str = "auto", passes: int = 2, regions=None, eta: float = 1.4,
                        mfp_range=(0.05, 8.0), radius_mm: float | None = None, fit_options: dict | None = None,
                        subsurface_options: dict | None = None, first: Fit | None = None,
                        options: FitOptions | None = None) -> Fit:
    """The BRDF ladder and the subsurface rung fitted by alternation (module
    docstring): ``relight.fit(model, normals)``, ``relight.fit_subsurface(per)``,
    then ``passes - 1`` rounds of (lobe refit on the capture minus the
    predicted subsurface radiance, subsurface refit). ``passes=1`` is the plain
    sequence. ``fit_options`` / ``subsurface_options``: further keywords of
    the two fits (``relight.fit``'s model choices: solver, loss, ...; the loss defaults to
    ``SUBSURFACE_LOSS``, "cauchy", not ``relight.fit``'s "l2": docs/fit.md, "Defaults").
    ``options``: how the BRDF fits run (``FitOptions``); its ``progress``
    also reports the subsurface fits. ``first``: a ``relight.fit`` of this
    capture already made with these ``model`` / ``normals`` / options (step 1
    is skipped). Returns
    the final ``Fit`` (rho_d: the profile albedo on the subsurface rung, the
    local Lambert albedo elsewhere)."""
    if not (isinstance(passes, int) and passes >= 1):
        raise ValueError(f"fit_with_subsurface: passes must be an int >= 1, got {passes!r}")
    fo = {"loss": SUBSURFACE_LOSS, **(fit_options or {})}
    options = as_options(options)
    progress = options.progress
    so = dict(subsurface_options or {})
    radius = default_radius_mm(mfp_range[1]) if radius_mm is None else float(radius_mm)
    if first is None:
        first = fit(capture, surface, model=model, normals=normals, options=options, **fo)
    elif first.rho_d.shape[0] != surface.num_samples:
        raise ValueError(f"fit_with_subsurface: first has {first.rho_d.shape[0]} samples, the surface "
                         f"{surface.num_samples}")
    out = fit_subsurface(capture, surface, first, per=per, regions=regions, eta=eta, mfp_range=mfp_range,
                         radius_mm=radius, progress=progress, **so)
    frame = first.maps(surface).frame(surface)
    labels = np.zeros(surface.num_samples, np.int64) if regions is None else np.asarray(regions)
    if passes > 1:
        diffuse_only = fit(capture, frame, model="lambert", normals=False, options=options, **fo)
    for _ in range(passes - 1):
        # The lobe must not depend on the ladder's choice for the diffuse term: predict subsurface
        # everywhere, the samples on no subsurface rung taking their region's (median) mean free path.
        pred = subsurface_radiance(capture, surface, _everywhere(out, labels, diffuse_only.rho_d), eta=eta,
                                   radius_mm=radius)
        rest = stage.Capture(capture.radiance - jnp.asarray(pred, capture.radiance.dtype), capture.mask, capture.rig,
                             capture.cameras, getattr(capture, "sensor", None))
        lobe = fit(rest, frame, model=model, normals=False, options=options, **fo)
        # The lobe's own diffuse albedo is what the predicted subsurface left over, not an albedo: every
        # sample starts from the first fit's (fit_subsurface solves the local rung's albedo again).
        result = np.where(np.asarray(first.result) != 0, np.asarray(first.result), np.asarray(lobe.result))
        merged = dataclasses.replace(first, rho_s=lobe.rho_s,
                                     alpha=lobe.alpha, normal=lobe.normal, tangent=lobe.tangent, model=lobe.model,
                                     result=jnp.asarray(result, jnp.int32), steps=first.steps + lobe.steps)
        out = fit_subsurface(capture, surface, merged, per=per, regions=regions, eta=eta, mfp_range=mfp_range,
                             radius_mm=radius, progress=progress, **so)
    return out
