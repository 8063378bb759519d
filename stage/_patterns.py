"""Pattern captures: a light stage frame in which every light shines at once,
light l at weight W[k, l] in [0, 1] (the same for every colour channel).

By linearity of light a pattern frame is the weighted sum of the OLAT frames,

    I_k(p, v) = sum_l W[k, l] L_l(p, v),      L_l = f_r cos_i E_l V_l   (stage._forward)

so a pattern capture holds K frames instead of L. It is what Kang et al. 2018
("Efficient Reflectance Capture Using an Autoencoder") learn the weights of
(the non-negative, bounded first layer of their encoder) and what spherical
gradient illumination (Ma et al. 2007) is with K = 4. The sensor exposes each
pattern frame once, so its noise is per pattern measurement (shot noise of the
summed signal), not per light: ``sense_patterns``.

``capture_patterns`` sums an OLAT capture; ``simulate_patterns`` renders the
pattern frames directly, one (light chunk x sample chunk) block at a time,
without the [V, L, P, C] OLAT array; ``gradient_patterns`` gives Ma et al.'s
patterns as [0, 1] weights.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._camera import Camera
from ._capture import Capture
from ._forward import _traced, as_float, widest_float
from ._rig import Rig
from ._sensor import Sensor
from ._simulate import _chunks, _prepare

__all__ = ["PatternCapture", "capture_patterns", "check_patterns", "gradient_patterns", "sense_patterns",
           "simulate_patterns"]


def _concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def check_patterns(patterns, num_lights: int, dtype=None) -> Array:
    """``patterns`` as a checked float array [K, L]: 2-D, L = ``num_lights``, K >= 1, finite and within [0, 1].

    A light cannot shine at a negative or beyond full power. The value checks are skipped for traced input (a
    pattern being learned under ``jax.grad``).

    Args:
        patterns: light weights [K, L].
        num_lights: the rig's L.
        dtype: the float dtype (None: float32 for non-JAX input, else its own float dtype).

    Returns:
        The patterns [K, L].

    Raises:
        ValueError: naming ``patterns``.
    """
    traced = isinstance(patterns, jax.core.Tracer)
    if not traced:
        try:
            a = np.asarray(patterns)
        except (TypeError, ValueError) as err:
            raise ValueError(f"patterns must be a [K, L] array of numbers in [0, 1] ({err})") from None
        if a.dtype == bool or not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
            raise ValueError(f"patterns must be a [K, L] array of numbers in [0, 1], got dtype {a.dtype}")
    shape = tuple(jnp.shape(patterns))
    if len(shape) != 2 or shape[0] < 1:
        raise ValueError(f"patterns must have shape [K, L] with K >= 1, got {shape}")
    if shape[1] != num_lights:
        raise ValueError(f"patterns has {shape[1]} light weights per pattern but the rig has {num_lights} lights")
    if not traced:
        a = np.asarray(patterns, np.float64)
        if not np.all(np.isfinite(a)):
            k, l = np.argwhere(~np.isfinite(a))[0]
            raise ValueError(f"patterns must be finite: pattern {k}, light {l} is {a[k, l]}")
        if np.any(a < 0) or np.any(a > 1):
            k, l = np.argwhere((a < 0) | (a > 1))[0]
            raise ValueError(f"patterns must be weights in [0, 1]: pattern {k}, light {l} is {a[k, l]:.6g}")
    if dtype is None:
        dtype = patterns.dtype if isinstance(patterns, jax.Array) and jnp.issubdtype(patterns.dtype, jnp.floating) \
            else jnp.float32
    return jnp.asarray(patterns, dtype)


class PatternCapture(eqx.Module):
    """A pattern capture: ``radiance`` [V, K, P, C] (pattern k's frame, in the
    units of the ``stage.Capture`` it sums: irradiance units x sr^-1),
    ``valid`` [V, P] bool (the sample is seen by view v, front-facing and lit
    by at least one light), the ``patterns`` [K, L] in [0, 1], the ``rig``, the
    ``cameras`` (one per view), the ``sensor`` that exposed it (None:
    noise-free) and ``saturated`` [V, K, P] bool (a pattern measurement that
    hit the full well or the white level; None: none did)."""

    radiance: Float[Array, "view pattern sample channel"]
    valid: Bool[Array, "view sample"]
    patterns: Float[Array, "pattern light"]
    rig: Rig
    cameras: tuple[Camera, ...]
    sensor: Any = None
    saturated: Bool[Array, "view pattern sample"] | None = None

    def __check_init__(self):
        V, K, P, _ = self.radiance.shape
        if self.valid.shape != (V, P):
            raise ValueError(f"PatternCapture.valid must have shape {(V, P)}, got {self.valid.shape}")
        if self.patterns.shape != (K, self.rig.num_lights):
            raise ValueError(f"PatternCapture.patterns must have shape {(K, self.rig.num_lights)} (patterns x the "
                             f"rig's lights), got {self.patterns.shape}")
        if len(self.cameras) != V:
            raise ValueError(f"PatternCapture has {V} views but {len(self.cameras)} cameras")
        if self.saturated is not None and self.saturated.shape != (V, K, P):
            raise ValueError(f"PatternCapture.saturated must have shape {(V, K, P)}, got {self.saturated.shape}")

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return tuple(self.radiance.shape)

    @property
    def num_patterns(self) -> int:
        return self.radiance.shape[1]

    @property
    def mask(self) -> Bool[Array, "view pattern sample"]:
        """[V, K, P]: usable measurements (seen by the view and not saturated)."""
        m = jnp.broadcast_to(self.valid[:, None, :], self.radiance.shape[:3])
        return m if self.saturated is None else m & ~self.saturated

    def select(self, index) -> PatternCapture:
        """The capture restricted to the patterns ``index``."""
        index = jnp.asarray(index)
        sat = None if self.saturated is None else self.saturated[:, index]
        return PatternCapture(radiance=self.radiance[:, index], valid=self.valid, patterns=self.patterns[index],
                              rig=self.rig, cameras=self.cameras, sensor=self.sensor, saturated=sat)


def capture_patterns(capture: Capture, patterns) -> PatternCapture:
    """The pattern capture an OLAT capture stands for: frame k = sum_l W[k, l] x OLAT frame l (linearity of light).

    Each observation the capture's mask leaves out (shadowed, behind the surface, saturated) counts 0, as it does
    in the OLAT images. Differentiable in the radiance and the patterns (jit / grad / vmap).

    Args:
        capture: an OLAT capture.
        patterns: light weights W [K, L] in [0, 1] (ValueError naming ``patterns`` otherwise).

    Returns:
        The ``PatternCapture``; its ``valid`` [V, P] is True where the sample has any valid OLAT observation in the
        view.

    References:
        Kang et al. 2018, "Efficient reflectance capture using an autoencoder", eq. 1; Debevec et al. 2000,
        "Acquiring the reflectance field of a human face" (image-based relighting).
    """
    V, L, P, C = capture.radiance.shape
    # A float16 capture is summed in float32 (hundreds of terms would lose float16's 11 bits).
    dt = jnp.float32 if jnp.dtype(capture.radiance.dtype).itemsize < 4 else capture.radiance.dtype
    W = check_patterns(patterns, L, dt)
    rad = jnp.where(capture.mask[..., None], capture.radiance.astype(dt), jnp.zeros((), dt))
    out = jnp.einsum("kl,vlpc->vkpc", W, rad)
    return PatternCapture(radiance=out, valid=jnp.any(capture.mask, axis=1), patterns=W, rig=capture.rig,
                          cameras=tuple(capture.cameras))


def sense_patterns(pcapture: PatternCapture, sensor: Sensor, key) -> PatternCapture:
    """The pattern capture as ``sensor`` records it, one noisy exposure per pattern frame.

    The radiance is replaced by ``sensor.to_radiance(DN)`` of one exposure of each pattern measurement, so the shot
    noise is that of the summed signal: Var = (gain / (wb exposure))^2 (exposure I_k + read^2) in radiance units.

    Args:
        pcapture: the noise-free pattern capture.
        sensor: the camera sensor.
        key: a ``jax.random`` key.

    Returns:
        The ``PatternCapture`` with saturated measurements marked in ``saturated`` and the sensor attached.

    References:
        Foi et al. 2008, "Practical Poissonian-Gaussian noise modeling and fitting for single-image raw-data",
        eq. 1-3.
    """
    if not isinstance(sensor, Sensor):
        raise ValueError(f"sense_patterns: sensor must be a stage.Sensor, got {type(sensor).__name__}")
    dn, sat = sensor.expose(key, pcapture.radiance)
    rad = sensor.to_radiance(dn).astype(pcapture.radiance.dtype)
    if pcapture.saturated is not None:
        sat = sat | pcapture.saturated
    return PatternCapture(radiance=rad, valid=pcapture.valid, patterns=pcapture.patterns, rig=pcapture.rig,
                          cameras=pcapture.cameras, sensor=sensor, saturated=sat)


def gradient_patterns(rig: Rig, complement: bool = False) -> Float[Array, "pattern light"]:
    """Spherical gradient illumination as light weights in [0, 1].

    The full-on sphere P_f = 1 and the gradients P_i = (1 + w_i) / 2, i in {x, y, z}; with ``complement`` the
    gradients and their complements (1 - w_i) / 2 (P_i + its complement = P_f). Each light stands for its Voronoi
    cell: weight P(w_l) Omega_l / E_l as ``stage.gradient_weights`` (E_l the light's irradiance at the centre,
    channels averaged), then the whole set is scaled by one factor so that its largest weight is 1 (ratios between
    patterns, such as I_i / I_f = 1/2 + n_i/3, are kept).

    Args:
        rig: the light rig.
        complement: the six gradients and complements instead of the full-on sphere and three gradients.

    Returns:
        Weights [4, L] (full, x, y, z, the order of ``stage.PATTERNS``), or [6, L] (x, y, z, -x, -y, -z).

    References:
        Ma et al. 2007, "Rapid acquisition of specular and diffuse normal maps from polarized spherical gradient
        illumination", eq. 2.
    """
    d = rig.directions
    e = jnp.mean(rig.center_irradiance, axis=-1)
    cell = rig.solid_angle.astype(d.dtype) / e.astype(d.dtype)
    grad = 0.5 * (1.0 + d.T)  # [3, L]
    if complement:
        p = jnp.concatenate([grad, 0.5 * (1.0 - d.T)], axis=0)
    else:
        p = jnp.concatenate([jnp.ones((1, rig.num_lights), d.dtype), grad], axis=0)
    w = p * cell[None]
    top = jnp.max(w)
    if _concrete(top) and not float(top) > 0:
        raise ValueError("gradient_patterns: the rig's lights have no solid angle or no irradiance at the centre")
    return jnp.clip(w / top, 0.0, 1.0)


def _pattern_chunks(chunks, W, K: int):
    """Accumulate the OLAT chunks of ``stage._simulate._chunks`` (one view and
    sample chunk at a time, its light chunks in order) into pattern blocks:
    yields (view, sample slice, radiance [K, Pc, C], valid [Pc]). Only one
    light chunk of OLAT radiance and one [K, Pc, C] accumulator are alive."""
    cur, cur_ps, acc, seen = None, None, None, None
    for v, ls, ps, rad, msk in chunks:
        if cur is not None and cur != (v, ps.start):
            yield cur[0], cur_ps, acc, seen
            acc = None
        cur, cur_ps = (v, ps.start), ps
        term = jnp.einsum("kl,lpc->kpc", W[:, ls].astype(rad.dtype), rad)
        hit = jnp.any(jnp.asarray(msk), axis=0)
        acc, seen = (term, hit) if acc is None else (acc + term, seen | hit)
    if cur is not None:
        yield cur[0], cur_ps, acc, seen


def simulate_patterns(surface, rig: Rig, cameras, material, light_visibility, camera_visibility, patterns, *,
                      light_chunk: int = 64, sample_chunk: int = 1 << 14, dtype=None, progress=None,
                      polarization: str | None = None, subsurface=None) -> PatternCapture:
    """Simulate a pattern capture directly, never holding the [V, L, P, C] OLAT capture.

    What ``capture_patterns(simulate(...), patterns)`` gives, computed one (light chunk x sample chunk) block of
    the one OLAT forward model at a time and summed into the [V, K, P, C] pattern frames: peak memory beyond the
    output is light_chunk x sample_chunk x C floats plus one K x sample_chunk x C accumulator. Differentiable as
    ``simulate`` is (the material, surface, rig, cameras and the patterns).

    Args:
        surface, rig, cameras, material, light_visibility, camera_visibility: as ``stage.simulate``.
        patterns: light weights [K, L] in [0, 1] (ValueError naming ``patterns`` otherwise).
        light_chunk: lights per block.
        sample_chunk: samples per block; with ``subsurface`` the sample axis is not chunked (the diffusion
            operator couples samples).
        dtype, polarization, subsurface: as ``stage.simulate``.
        progress: as ``stage.simulate``; counts (view, light) images per sample chunk, phase "simulate".

    Returns:
        The ``PatternCapture`` [V, K, P, C].
    """
    cameras, lv, cv, terms, sss_weight = _prepare(surface, rig, cameras, material, light_visibility,
                                                  camera_visibility, polarization, subsurface)
    # simulate's float policy (the patterns, light weights, do not set it); the capture records the rig and
    # cameras as given.
    wide = widest_float(material, surface, rig, cameras, subsurface)
    surface_w, rig_w, cameras_w, terms = as_float((surface, rig, cameras, terms), wide)
    if int(light_chunk) < 1 or int(sample_chunk) < 1:
        raise ValueError(f"simulate_patterns: light_chunk and sample_chunk must be >= 1, got {light_chunk}, "
                         f"{sample_chunk}")
    P, L = surface.num_samples, rig.num_lights
    dtype = wide if dtype is None else dtype
    W = check_patterns(patterns, L, jnp.dtype(dtype) if _concrete(patterns) else None)
    K = W.shape[0]
    sc = P if subsurface is not None else min(int(sample_chunk), P)
    chunks = _chunks(surface_w, rig_w, cameras_w, terms, sss_weight, subsurface, lv, cv, int(light_chunk), sc,
                     progress)
    blocks = _pattern_chunks(chunks, W, K)
    if _traced(surface, rig, cameras, material, subsurface, W):
        views_r, views_m = [[] for _ in cameras], [[] for _ in cameras]
        for v, _, rad, seen in blocks:
            views_r[v].append(rad.astype(dtype))
            views_m[v].append(seen)
        radiance = jnp.stack([jnp.concatenate(r, axis=1) for r in views_r])
        valid = jnp.stack([jnp.concatenate(m, axis=0) for m in views_m])
        return PatternCapture(radiance=radiance, valid=valid, patterns=W.astype(dtype), rig=rig, cameras=cameras)
    radiance, valid = None, np.zeros((len(cameras), P), bool)
    for v, ps, rad, seen in blocks:
        if radiance is None:
            radiance = np.zeros((len(cameras), K, P, rad.shape[-1]), dtype)
        radiance[v, :, ps] = np.asarray(rad.astype(dtype))
        valid[v, ps] = np.asarray(seen)
    return PatternCapture(radiance=jnp.asarray(radiance), valid=jnp.asarray(valid), patterns=W.astype(dtype),
                          rig=rig, cameras=cameras)
