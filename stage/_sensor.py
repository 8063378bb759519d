"""A camera sensor: exposure, Poisson-Gaussian noise, saturation, white
balance, black level and quantisation, after the standard raw-sensor model
(Foi et al. 2008, "Practical Poissonian-Gaussian noise modeling and fitting for
single-image raw-data", eq. 1-3; Healey & Kondepudy 1994).

For a radiance L (capture units) in channel c:

    e  = exposure * L                          expected photo-electrons
    e~ ~ Poisson(e) + N(0, read_noise^2)       (each term optional)
    e~ = min(e~, full_well)                    saturation (full_well optional)
    DN = wb_c * e~ / gain + black_level        digital numbers (gain: e- per DN)
    DN = round(clip(DN, 0, 2^bits - 1))        quantisation (bits optional)

so E[DN] = wb_c exposure L / gain + black_level and
Var[DN] = (wb_c / gain)^2 (e + read_noise^2) (+ 1/12 when quantised), away from
the clipping points. An observation is saturated when e~ reaches the full well
or DN reaches the white level 2^bits - 1; ``sense`` marks it invalid in the mask.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ._capture import Capture


def _f32(x):
    return None if x is None else jnp.asarray(x, jnp.float32)


def _concrete(x):
    return x is not None and not isinstance(x, jax.core.Tracer)


class Sensor(eqx.Module):
    """Sensor parameters (see the module docstring). ``exposure``: electrons per
    unit radiance (exposure time x QE x pixel etendue, lumped); ``gain``:
    electrons per DN; ``white_balance`` [C] digital gains (or one scalar); ``black_level``
    DN; ``read_noise`` electrons (std); ``shot_noise`` on/off; ``full_well``
    electrons (inf: never saturates); ``bits`` (0 or None: no quantisation, no white level)."""

    # Numbers are stored as arrays (traced, not static) so that sensors with
    # different settings share one compilation of ``expose``.
    exposure: Float[Array, ""] = eqx.field(default=1000.0, converter=_f32)
    gain: Float[Array, ""] = eqx.field(default=1.0, converter=_f32)
    white_balance: Float[Array, "*channel"] = eqx.field(default=1.0, converter=_f32)
    black_level: Float[Array, ""] = eqx.field(default=0.0, converter=_f32)
    read_noise: Float[Array, ""] = eqx.field(default=0.0, converter=_f32)
    shot_noise: bool = eqx.field(static=True, default=False)
    full_well: Float[Array, ""] = eqx.field(default=float("inf"), converter=_f32)
    bits: Int[Array, ""] = eqx.field(default=0, converter=lambda b: jnp.asarray(0 if b is None else b, jnp.int32))

    def __check_init__(self):
        for name, lo, strict in (("exposure", 0, True), ("gain", 0, True), ("black_level", 0, False),
                                 ("read_noise", 0, False), ("full_well", 0, True)):
            v = getattr(self, name)
            if _concrete(v):
                a = np.asarray(v)
                out_of_range = np.any(a <= lo) if strict else np.any(a < lo)
                if np.any(np.isnan(a)) or (name != "full_well" and not np.all(np.isfinite(a))) or out_of_range:
                    raise ValueError(f"Sensor.{name} must be finite and {'>' if strict else '>='} {lo}, got {a}")
        if _concrete(self.bits) and not (0 <= int(self.bits) <= 24):
            raise ValueError(f"Sensor.bits must be in [1, 24] (0 or None: no quantisation), got {int(self.bits)}")
        if _concrete(self.white_balance) and np.any(np.asarray(self.white_balance) <= 0):
            raise ValueError("Sensor.white_balance gains must be > 0")

    @property
    def white_level(self) -> Float[Array, ""]:
        """Largest digital number, 2^bits - 1 (inf without quantisation)."""
        return jnp.where(self.bits > 0, 2.0 ** self.bits.astype(jnp.float32) - 1.0, jnp.inf)

    def _wb(self, shape, dtype):
        """White-balance gains shaped [1, ..., 1, C] to match an array of ``shape``."""
        wb = jnp.asarray(self.white_balance, dtype)
        if wb.ndim == 0:
            return jnp.broadcast_to(wb, (1,) * len(shape))
        if wb.shape != (shape[-1],):
            raise ValueError(f"Sensor.white_balance has shape {wb.shape} for {shape[-1]} channels")
        return wb.reshape((1,) * (len(shape) - 1) + (shape[-1],))

    def _as(self, dtype, *names):
        """The float32 parameters ``names`` cast to ``dtype`` (the radiance's: float64 in
        float64 tests), so the arithmetic with it needs no implicit promotion."""
        return tuple(jnp.asarray(getattr(self, n), dtype) for n in names)

    def mean(self, radiance: Float[ArrayLike, "*batch channel"]) -> Float[Array, "*batch channel"]:
        """Expected DN (before clipping and rounding): wb exposure L / gain + black_level."""
        L = jnp.asarray(radiance)
        exposure, gain, black_level = self._as(L.dtype, "exposure", "gain", "black_level")
        return self._wb(L.shape, L.dtype) * exposure * L / gain + black_level

    def variance(self, radiance: Float[ArrayLike, "*batch channel"]) -> Float[Array, "*batch channel"]:
        """Model variance of DN (before clipping): (wb/gain)^2 (shot e + read^2) + 1/12 if quantised."""
        L = jnp.asarray(radiance)
        exposure, gain, read_noise = self._as(L.dtype, "exposure", "gain", "read_noise")
        e = exposure * L
        var_e = (e if self.shot_noise else 0.0 * e) + read_noise**2
        q = jnp.where(self.bits > 0, 1.0 / 12.0, 0.0)
        return (self._wb(L.shape, L.dtype) / gain) ** 2 * var_e + q

    def expose(self, key, radiance: Float[ArrayLike, "*batch channel"]):
        """Raw digital numbers and the saturation flags: (DN [*batch, C] float,
        saturated [*batch] bool, true where any channel saturates). Seeded by
        ``key`` (jax.random); deterministic when no noise is enabled."""
        radiance = jnp.asarray(radiance, jnp.float32)  # strong float32: no recompiles on weak types
        # One white-balance shape per channel count: sensors differing only in
        # their numbers then share a compilation.
        wb = jnp.broadcast_to(jnp.asarray(self.white_balance, jnp.float32), radiance.shape[-1:])
        return _expose(eqx.tree_at(lambda s: s.white_balance, self, wb), key, radiance)

    def _expose(self, key, radiance):
        L = jnp.maximum(jnp.asarray(radiance, jnp.float32), 0.0)
        e = self.exposure * L
        k_shot, k_read = jax.random.split(key)
        if self.shot_noise:
            # Beyond the full well the value is clipped anyway: cap the rate there
            # (and at 2^30) so the integer Poisson draw cannot overflow.
            cap = jnp.minimum(4.0 * self.full_well, 2.0**30)
            e = jax.random.poisson(k_shot, jnp.minimum(e, cap), e.shape).astype(jnp.float32)
        e = e + self.read_noise * jax.random.normal(k_read, e.shape, jnp.float32)
        sat = e >= self.full_well
        e = jnp.minimum(e, self.full_well)
        dn = self._wb(e.shape, e.dtype) * e / self.gain + self.black_level
        sat = sat | (dn >= self.white_level)
        dn = jnp.clip(dn, 0.0, self.white_level)
        dn = jnp.where(self.bits > 0, jnp.round(dn), dn)
        return dn, jnp.any(sat, axis=-1)

    def to_radiance(self, dn: Float[ArrayLike, "*batch channel"]) -> Float[Array, "*batch channel"]:
        """Invert the mean response: (DN - black_level) gain / (wb exposure), in radiance units."""
        dn = jnp.asarray(dn)
        exposure, gain, black_level = self._as(dn.dtype, "exposure", "gain", "black_level")
        return (dn - black_level) * gain / (self._wb(dn.shape, dn.dtype) * exposure)


@eqx.filter_jit
def _expose(sensor: Sensor, key, radiance):
    return sensor._expose(key, radiance)


def sense(capture: Capture, sensor: Sensor, key) -> Capture:
    """The capture as ``sensor`` records it: radiance replaced by the
    linearised noisy measurement ``sensor.to_radiance(DN)`` (same units as
    before), saturated observations removed from the mask, the sensor attached."""
    dn, sat = sensor.expose(key, capture.radiance)
    rad = sensor.to_radiance(dn).astype(capture.radiance.dtype)
    return Capture(radiance=rad, mask=capture.mask & ~sat, rig=capture.rig, cameras=capture.cameras, sensor=sensor)


def observation_key(seed, view, light, sample):
    """The PRNG key of one observation: the project's one sensor-noise seeding rule.

    key = fold_in(fold_in(fold_in(PRNGKey(seed), view), light), sample), so an
    observation's noise is a function of (seed, view, light, sample) only: it does
    not depend on how a capture is cut into chunks or blocks, nor on the form it
    is written in.

    Args:
        seed: an integer seed, or a ``jax.random`` key (``PRNGKey(seed)`` already made).
        view: the camera's index in the capture.
        light: the light's index in the rig.
        sample: the sample's index on its grid (``Surface.texel_index``: the texel of a
            texel grid, the pixel ``row * width + column`` of an image).

    Returns:
        A ``jax.random`` key.
    """
    return jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(_key(seed), view), light), sample)


def _key(seed):
    """``PRNGKey(seed)`` of an integer seed; a key (typed, or raw uint32 [2]) as it is."""
    if hasattr(seed, "dtype") and jnp.issubdtype(seed.dtype, jax.dtypes.prng_key):
        return seed
    return jax.random.PRNGKey(seed) if jnp.ndim(seed) == 0 else jnp.asarray(seed)


# Observations per call of the keyed exposure: every chunk is cut into tiles of this many (the last one padded
# with zeros), so the program, whose vmapped Poisson sampler takes seconds to compile, is built once per
# sensor kind and channel count, whatever the chunk shapes of a capture; ~0.2 MB of float32 a tile.
_SENSE_TILE = 1 << 14


@eqx.filter_jit
def _sense_tile(sensor: Sensor, key, view, lights, samples, radiance):
    """``sensor.expose`` of each observation n of a tile with its own key (:func:`observation_key`
    ``(key, view, lights[n], samples[n])``): (radiance [T, C] float32, saturated [T])."""
    kv = jax.random.fold_in(key, view)

    def one(light, sample, rad):
        dn, sat = sensor.expose(jax.random.fold_in(jax.random.fold_in(kv, light), sample), rad)
        return sensor.to_radiance(dn), sat

    return jax.vmap(one)(lights, samples, radiance)


def _sense_keyed(sensor: Sensor, key, view, lights, samples, radiance, mask):
    """:func:`sense_keyed`'s measurement of a chunk [Lc, Pc, C] in tiles of ``_SENSE_TILE`` observations."""
    lc, pc, c = radiance.shape
    n = lc * pc
    total = -(-n // _SENSE_TILE) * _SENSE_TILE
    pad = lambda a: np.concatenate([a, np.zeros((total - n,) + a.shape[1:], a.dtype)])  # noqa: E731
    flat = pad(radiance.reshape(n, c))
    light = pad(np.repeat(np.asarray(lights, np.int32), pc))
    sample = pad(np.tile(np.asarray(samples, np.int32), lc))
    out = np.empty_like(flat)
    sat = np.empty(total, bool)
    view = jnp.asarray(view, jnp.int32)
    for s in range(0, total, _SENSE_TILE):
        t = slice(s, s + _SENSE_TILE)
        r, k = _sense_tile(sensor, key, view, jnp.asarray(light[t]), jnp.asarray(sample[t]), jnp.asarray(flat[t]))
        out[t], sat[t] = np.asarray(r), np.asarray(k)
    out, sat = out[:n], sat[:n]
    return out.reshape(lc, pc, c), mask & ~sat.reshape(lc, pc)


def sense_keyed(sensor: Sensor | None, seed, radiance: Float[ArrayLike, "light sample channel"], mask, *, view: int,
                lights, samples) -> tuple[np.ndarray, np.ndarray]:
    """One chunk of a capture as ``sensor`` records it, each observation with its own key.

    The noise of observation (view, light, sample) is drawn from
    :func:`observation_key` ``(seed, view, light, sample)`` (the one seeding rule),
    so the same observation gets the same noise whatever chunk it is in.

    Args:
        sensor: the ``Sensor``; None: no sensor (the radiance as it is, clipped at 0).
        seed: an integer seed (or a ``jax.random`` key).
        radiance: float [Lc, Pc, C], the chunk's radiance (capture units).
        mask: bool [Lc, Pc], the chunk's valid observations.
        view: the chunk's view index.
        lights: the rig index of the chunk's first light (an int; the rows are
            ``lights, lights + 1, ...``), or int [Lc], one per row.
        samples: int [Pc], each column's index on the sample grid (``Surface.texel_index``).

    Returns:
        (radiance float32 [Lc, Pc, C] >= 0, the linearised measurement
        ``sensor.to_radiance(DN)``; mask bool [Lc, Pc] without the saturated
        observations), as NumPy arrays.

    References:
        Foi et al. 2008, "Practical Poissonian-Gaussian noise modeling and fitting for
        single-image raw-data", eq. 1-3 (the noise model of ``Sensor.expose``).
    """
    radiance = np.asarray(radiance, np.float32)
    if radiance.ndim != 3:
        raise ValueError(f"sense_keyed: radiance must be [Lc, Pc, C], got shape {radiance.shape}")
    mask = np.asarray(mask, bool)
    if mask.shape != radiance.shape[:2]:
        raise ValueError(f"sense_keyed: mask has shape {mask.shape}, radiance {radiance.shape}")
    if sensor is not None:
        lc = radiance.shape[0]
        lights = np.asarray(lights, np.int64)
        lights = lights + np.arange(lc) if lights.ndim == 0 else lights
        samples = np.asarray(samples, np.int64)
        if lights.shape != (lc,) or samples.shape != radiance.shape[1:2]:
            raise ValueError(f"sense_keyed: lights {lights.shape} / samples {samples.shape} do not match radiance "
                             f"{radiance.shape}")
        radiance, mask = _sense_keyed(sensor, _key(seed), view, lights, samples, radiance, mask)
    return np.maximum(np.asarray(radiance, np.float32), 0.0), np.asarray(mask, bool)
