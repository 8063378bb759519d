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
