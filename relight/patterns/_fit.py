"""The fit path of a learned-pattern capture: the autoencoder's material
decoder reads each sample's pattern measurements (with the scanned geometry:
normal, view direction, position, light visibility) and its estimate starts
``relight.fitting.fit_patterns``, least squares on the pattern measurements
directly (Kang et al. 2018 sec. 5 refine their decoded BRDF the same way: the
network gives a start, the physical model the answer)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import brdf
import stage

from ..fitting import Fit, fit_patterns
from ._autoencoder import PatternAutoencoder
from ._lumitexels import geometry_features, specular_bases

# Samples decoded per call: the white lumitexels of a chunk are chunk x L x C floats (4 MiB at 1024 x 346 x 3),
# the specular bases of a grid model 2 J times that.
_DECODE_CHUNK = 1024


@eqx.filter_jit
def _decode_chunk(model, y, position, normal, tangent, bitangent, wo, vis, rig):
    wi_world, irr = stage.incident_light(rig.position, rig.intensity, rig.near_field, position)
    wi = stage.to_local(wi_world, tangent, bitangent, normal)
    wo_l = stage.to_local(wo, tangent, bitangent, normal)
    lit = (wi[..., 2] > 0) & vis.T
    white = stage.reflected_radiance_lights(brdf.Lambert(jnp.ones(position.shape[:1] + (irr.shape[-1],),
                                                                  position.dtype)), wi, wo_l, irr, lit)
    bases = None
    if model.grid:
        bases = specular_bases(rig, position, normal, tangent, bitangent, wo, vis, model.grid)
    return model.decode(y, jnp.swapaxes(white, 0, 1), geometry_features(normal, wo, position), bases)


def _views(pcapture: stage.PatternCapture) -> np.ndarray:
    """Per sample the first view that sees it (0 where none does)."""
    valid = np.asarray(pcapture.valid)
    return np.argmax(valid, axis=0)


def decoder_start(pcapture: stage.PatternCapture, surface: stage.Surface, light_visibility,
                  model: PatternAutoencoder, *, chunk: int = _DECODE_CHUNK) -> dict[str, np.ndarray]:
    """The decoder's Lambert + GGX material per sample from a pattern capture.

    Each sample is read in the first view that sees it.

    Args:
        pcapture: the pattern capture.
        surface: its samples.
        light_visibility: bool [P, L] (or a ``stage.PackedMask``), the shadowing the decoder's white-Lambertian
            normaliser uses.
        model: an autoencoder trained for this capture's patterns (ValueError naming ``model`` otherwise).
        chunk: samples decoded at a time.

    Returns:
        ``{"rho_d" [P, 3], "rho_s" [P] (Schlick F0), "alpha" [P]}`` (NumPy float32), the ``start`` that
        ``relight.fitting.fit_patterns`` takes.
    """
    W = np.asarray(pcapture.patterns, np.float32)
    if W.shape != tuple(model.logits.shape) or not np.allclose(W, np.asarray(model.patterns), atol=1e-5):
        raise ValueError(f"decoder_start: argument 'model' was not trained for this capture's patterns "
                         f"(model {tuple(model.logits.shape)}, capture {W.shape}, or different weights)")
    P = surface.num_samples
    lv = np.asarray(light_visibility, bool)
    if lv.shape != (P, pcapture.rig.num_lights):
        raise ValueError(f"decoder_start: light_visibility must have shape {(P, pcapture.rig.num_lights)}, "
                         f"got {lv.shape}")
    views = _views(pcapture)
    rad = np.asarray(pcapture.radiance, np.float32)  # [V, K, P, C]
    y = rad[views, :, np.arange(P)]  # [P, K, C]
    pos = np.asarray(surface.position, np.float32)
    wo = np.zeros_like(pos)
    for v, cam in enumerate(pcapture.cameras):
        sel = views == v
        if np.any(sel):
            wo[sel] = np.asarray(cam.view_directions(jnp.asarray(pos[sel])), np.float32)
    r = pcapture.rig
    rig = stage.Rig(position=jnp.asarray(r.position, jnp.float32), intensity=jnp.asarray(r.intensity, jnp.float32),
                    solid_angle=jnp.asarray(r.solid_angle, jnp.float32), near_field=r.near_field)
    f = lambda a, idx: jnp.asarray(np.asarray(a, np.float32)[idx])  # noqa: E731
    out = {"rho_d": np.zeros((P, 3), np.float32), "rho_s": np.zeros(P, np.float32), "alpha": np.zeros(P, np.float32)}
    size = min(chunk, P)
    for s in range(0, P, size):
        idx = np.minimum(np.arange(s, s + size), P - 1)  # the last chunk padded: one compilation
        n = min(s + size, P) - s
        d = _decode_chunk(model, f(y, idx), f(pos, idx), f(surface.normal, idx), f(surface.tangent, idx),
                          f(surface.bitangent, idx), f(wo, idx), jnp.asarray(lv[idx]), rig)
        for k in out:
            out[k][s:s + n] = np.asarray(d[k])[:n]
    return out


def fit_learned(pcapture: stage.PatternCapture, surface: stage.Surface, light_visibility,
                model: PatternAutoencoder, **fit_kw) -> Fit:
    """Fit Lambert + GGX per sample to a learned-pattern capture, starting from the decoder's estimate.

    ``relight.fitting.fit_patterns(pcapture, surface, light_visibility, model="ggx", start=decoder_start(...))``;
    the decoder alone is ``decoder_start``.

    Args:
        pcapture: the pattern capture.
        surface: its samples.
        light_visibility: bool [P, L] (or a ``stage.PackedMask``).
        model: an autoencoder trained for this capture's patterns.
        **fit_kw: passed on to ``fit_patterns``: ``normals``, ``solver``, ``loss``, ``cauchy``,
            ``alpha_floor``, and ``options`` (a :class:`relight.fitting.FitOptions`: ``chunk``, ``block``,
            ``steps_per_round``, ``rounds``, ``devices``, ``progress``, ...).

    Returns:
        The ``Fit``.

    References:
        Kang et al. 2018, "Efficient reflectance capture using an autoencoder".
    """
    start = decoder_start(pcapture, surface, light_visibility, model)
    return fit_patterns(pcapture, surface, light_visibility, model="ggx", start=start, **fit_kw)
