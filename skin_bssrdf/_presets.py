"""Measured scattering coefficients of Jensen, Marschner, Levoy & Hanrahan 2001,
"A Practical Model for Subsurface Light Transport", Figure 5 (table of
sigma_s', sigma_a in 1/mm and diffuse reflectance Rd for the R, G, B channels).

Transcribed from the paper's table as reproduced in pbrt-v3 (src/core/medium.cpp,
``SubsurfaceParameterTable``) and in the DirectX SDK PRT sample (which also keeps
the Rd column and the index of refraction). All materials use eta = 1.3 except
marble, eta = 1.5: only with 1.5 does eq. 5 reproduce marble's Rd column (within
0.005; with 1.3 it is off by 0.04-0.05), and the DirectX transcription lists 1.5.

The Rd column is reproduced from the coefficients by eq. 5 within 0.008 for every
entry but one: chicken1's blue channel, 0.126 by eq. 5 against 0.10 in the table
(a discrepancy in the paper's own table; chicken2, measured the same way, agrees).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp

from ._better_dipole import BetterDipole
from ._dipole import Dipole

# Relative refractive index of skin (epidermis over air), the one home of the value every skin default uses
# (stage.Subsurface, the fitter, the renderer, the CLI): Jensen et al. 2001 and Donner & Jensen 2005 use 1.4
# for skin; Tuchin's measurements of the stratum corneum give 1.4-1.55.
SKIN_ETA = 1.4


@dataclasses.dataclass(frozen=True)
class MeasuredMaterial:
    """One row of Jensen et al. 2001's table: RGB sigma_s' and sigma_a (1/mm), Rd, eta."""

    sigma_s_prime: tuple[float, float, float]
    sigma_a: tuple[float, float, float]
    rd: tuple[float, float, float]
    eta: float = 1.3


JENSEN2001: dict[str, MeasuredMaterial] = {
    "apple": MeasuredMaterial((2.29, 2.39, 1.97), (0.0030, 0.0034, 0.046), (0.85, 0.84, 0.53)),
    "chicken1": MeasuredMaterial((0.15, 0.21, 0.38), (0.015, 0.077, 0.19), (0.31, 0.15, 0.10)),
    "chicken2": MeasuredMaterial((0.19, 0.25, 0.32), (0.018, 0.088, 0.20), (0.32, 0.16, 0.10)),
    "cream": MeasuredMaterial((7.38, 5.47, 3.15), (0.0002, 0.0028, 0.0163), (0.98, 0.90, 0.73)),
    "ketchup": MeasuredMaterial((0.18, 0.07, 0.03), (0.061, 0.97, 1.45), (0.16, 0.01, 0.00)),
    "marble": MeasuredMaterial((2.19, 2.62, 3.00), (0.0021, 0.0041, 0.0071), (0.83, 0.79, 0.75), eta=1.5),
    "potato": MeasuredMaterial((0.68, 0.70, 0.55), (0.0024, 0.0090, 0.12), (0.77, 0.62, 0.21)),
    "skimmilk": MeasuredMaterial((0.70, 1.22, 1.90), (0.0014, 0.0025, 0.0142), (0.81, 0.81, 0.69)),
    "skin1": MeasuredMaterial((0.74, 0.88, 1.01), (0.032, 0.17, 0.48), (0.44, 0.22, 0.13)),
    "skin2": MeasuredMaterial((1.09, 1.59, 1.79), (0.013, 0.070, 0.145), (0.63, 0.44, 0.34)),
    "spectralon": MeasuredMaterial((11.6, 20.4, 14.9), (0.0, 0.0, 0.0), (1.00, 1.00, 1.00)),
    "wholemilk": MeasuredMaterial((2.55, 3.21, 3.77), (0.0011, 0.0024, 0.014), (0.91, 0.88, 0.76)),
}


def preset(name: str, model: str = "dipole", dtype=None) -> Dipole | BetterDipole:
    """The diffusion profile of a material of Jensen et al. 2001's measured table.

    Args:
        name: a key of ``JENSEN2001``: apple, chicken1, chicken2, cream, ketchup, marble, potato, skimmilk, skin1,
            skin2, spectralon, wholemilk.
        model: ``"dipole"`` (a ``Dipole``) or ``"better_dipole"`` (a ``BetterDipole``).
        dtype: the profile's float dtype (None: the default float).

    Returns:
        The profile, with the material's sigma_a, sigma_s' (1/mm) and refractive index.

    References:
        Jensen et al. 2001, "A practical model for subsurface light transport", table of measured parameters.
    """
    key = name.lower().replace(" ", "").replace("_", "")
    if key not in JENSEN2001:
        raise ValueError(f"preset: unknown material {name!r}; known: {sorted(JENSEN2001)}")
    m = JENSEN2001[key]
    dtype = dtype or jnp.result_type(float)
    args = (jnp.asarray(m.sigma_a, dtype), jnp.asarray(m.sigma_s_prime, dtype), jnp.asarray(m.eta, dtype))
    if model == "dipole":
        return Dipole(*args)
    if model == "better_dipole":
        return BetterDipole(*args)
    raise ValueError(f"preset: model must be 'dipole' or 'better_dipole', got {model!r}")
