"""The subsurface model of a surface from per-sample maps: albedo and diffuse mean free path."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

import skin_bssrdf
from skin_bssrdf import SKIN_ETA

from ._simulate import Subsurface
from ._surface import Surface

# The mean free path floor (mm) of a scattering sample's zero channels: relight.materials' MaterialMaps.profile
# uses the same, so that a simulation and a render of its truth maps agree.
MFP_FLOOR_MM = 1e-3


def subsurface_from_maps(surface: Surface, albedo: Float[ArrayLike, "sample 3"],
                         mean_free_path: Float[ArrayLike, "sample 3"], eta: float = SKIN_ETA) -> Subsurface:
    """The ``Subsurface`` of ``surface`` with a Christensen-Burley profile per sample.

    Samples with a mean free path > 0 in some channel scatter with the profile of
    their ``albedo`` (the total diffuse reflectance) and mean free path (zero
    channels floored at ``MFP_FLOOR_MM``); the others get albedo 0 (no
    subsurface: their diffuse light must come from a local term of the material).
    The operator's neighbour radius is ``skin_bssrdf.operator_radius`` over the
    scattering samples (the one radius rule). The profile and operator are in
    float64 when JAX has x64 enabled, float32 otherwise.

    Args:
        surface: the P samples.
        albedo: float [P, 3], the diffuse albedo rho_d in [0, 1].
        mean_free_path: float [P, 3], the diffuse mean free path in mm (>= 0; 0 = no subsurface).
        eta: the relative index of refraction of the Fresnel transmittances (default skin's).

    Returns:
        A ``Subsurface`` (profile [P, 3], ``skin_bssrdf.DiffusionOperator`` on the samples, eta).

    Raises:
        ValueError: on shapes that do not match the surface, negative or non-finite
            values, or when no sample scatters.

    References:
        Christensen & Burley 2015, "Approximate Reflectance Profiles for Efficient
        Subsurface Scattering", eq. 3 and 6 (the profile) and the "dmfp" scale fit;
        Jensen et al. 2001, eq. 5 (the BSSRDF the operator integrates).
    """
    P = surface.num_samples
    rho = np.asarray(albedo, np.float64)
    mfp = np.asarray(mean_free_path, np.float64)
    for name, a in (("albedo", rho), ("mean_free_path", mfp)):
        if a.shape != (P, 3):
            raise ValueError(f"subsurface_from_maps: {name} must be [P, 3] = {(P, 3)}, got {a.shape}")
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ValueError(f"subsurface_from_maps: {name} must be finite and >= 0")
    if not (np.isfinite(eta) and eta > 1.0):
        raise ValueError(f"subsurface_from_maps: eta must be a finite number > 1, got {eta}")
    on = np.any(mfp > 0, axis=1)
    if not np.any(on):
        raise ValueError("subsurface_from_maps: the mean free path is 0 at every sample (nothing scatters)")
    dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    profile = skin_bssrdf.Burley.from_mean_free_path(jnp.asarray(rho * on[:, None], dt),
                                                     jnp.asarray(np.maximum(mfp, MFP_FLOOR_MM), dt), config="dmfp")
    radius = skin_bssrdf.operator_radius(profile, where=on)
    operator = skin_bssrdf.DiffusionOperator.build(np.asarray(surface.position), np.asarray(surface.area), radius,
                                                   dtype=dt)
    return Subsurface(profile, operator, float(eta))
