"""Jensen et al. 2001's measured scattering materials by name, as the diffuse
mean free path that the subsurface profiles take (``relight simulate
--subsurface NAME``)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

import skin_bssrdf

__all__ = ["preset_mean_free_path", "subsurface_presets"]


def subsurface_presets() -> tuple[str, ...]:
    """The measured materials that have a finite diffuse mean free path.

    Returns:
        The sorted names of ``skin_bssrdf.JENSEN2001``'s materials, all but those with sigma_a = 0 in some
        channel (spectralon), whose mean free path is infinite.
    """
    return tuple(sorted(k for k, m in skin_bssrdf.JENSEN2001.items() if min(m.sigma_a) > 0))


def preset_mean_free_path(name: str) -> tuple[np.ndarray, float]:
    """The diffuse mean free path and refractive index of a measured material.

    Args:
        name: a name of ``skin_bssrdf.JENSEN2001`` (case, spaces and underscores ignored: "Skin1", "skin_1").

    Returns:
        ``(mfp, eta)``: mfp [3] in mm, 1 / sigma_tr with sigma_tr = sqrt(3 sigma_a sigma_t') (independent of
        eta), what Christensen & Burley 2015's ``dmfp`` fit takes; eta, the material's refractive index.
        Raises ValueError for an unknown name (listing the known ones) or a material whose sigma_a = 0.

    References:
        Jensen, Marschner, Levoy and Hanrahan 2001, "A Practical Model for Subsurface Light Transport",
        table 2 (the materials); Jensen and Buhler 2002, "A Rapid Hierarchical Rendering Technique for
        Translucent Materials", sec. 4 (sigma_tr).
    """
    presets = subsurface_presets()
    key = name.lower().replace(" ", "").replace("_", "")
    if key not in presets:
        if key in skin_bssrdf.JENSEN2001:
            raise ValueError(f"{name}: sigma_a = 0, so its diffuse mean free path is infinite; "
                             f"choose one of {', '.join(presets)}")
        raise ValueError(f"{name}: not a preset ({', '.join(presets)}) nor an existing mean-free-path EXR")
    m = skin_bssrdf.JENSEN2001[key]
    _, mfp = skin_bssrdf.albedo_from_coefficients(jnp.asarray(m.sigma_a, jnp.float32),
                                                  jnp.asarray(m.sigma_s_prime, jnp.float32), m.eta)
    return np.asarray(mfp, np.float64), float(m.eta)
