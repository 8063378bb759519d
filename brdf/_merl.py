"""Measured BRDFs in the MERL binary format (Matusik et al. 2003): the
Rusinkiewicz half/difference parameterisation, the format's indexing, a reader,
tabulation of analytic models and tabulated evaluation.

File layout (MERL's BRDFRead.cpp): three little-endian int32 (90, 90, 180), then
3 x 90 x 90 x 180 little-endian float64, channel-major (all red, all green, all
blue), each channel stored divided by its scale (1/1500, 1.15/1500, 1.66/1500).
Axes: theta_h (square-root bins), theta_d, phi_d in [0, pi) (reciprocity folds
phi_d + pi onto phi_d). Negative stored values mark missing measurements.
The writer is ``relight.io.write_merl`` (brdf writes no files).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._base import AbstractBRDF, ParamSpec, check_directions, cos_theta
from ._safe import dot, safe_atan2, safe_sqrt, working_float

MERL_RES = (90, 90, 180)  # theta_h, theta_d, phi_d bins
MERL_SCALE = (1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0)  # red, green, blue
_N = MERL_RES[0] * MERL_RES[1] * MERL_RES[2]
_HEADER_BYTES = 12
_FILE_BYTES = _HEADER_BYTES + 8 * 3 * _N
INTERPOLATIONS = ("nearest", "linear")


def half_diff_coords(
    wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]
) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"], Float[Array, "*batch"], Float[Array, "*batch"]]:
    """Rusinkiewicz 1998 half/difference angles (theta_h, phi_h, theta_d, phi_d),
    in radians: h = normalize(wi + wo); d = wi rotated by -phi_h about the normal
    and by -theta_h about the bitangent (MERL's std_coords_to_half_diff_coords).
    phi values are in (-pi, pi]; undefined azimuths (h or d on the normal) are 0.
    """
    h = wi + wo
    hxy2 = h[..., 0] ** 2 + h[..., 1] ** 2
    hn = safe_sqrt(hxy2 + h[..., 2] ** 2)
    ok = hn > 0
    hn_s = jnp.where(ok, hn, 1.0)
    hx, hy, hz = h[..., 0] / hn_s, h[..., 1] / hn_s, jnp.where(ok, h[..., 2] / hn_s, 1.0)
    sin_h = safe_sqrt(hx * hx + hy * hy)
    theta_h = safe_atan2(sin_h, hz)  # accurate near the normal, unlike acos
    phi_h = safe_atan2(hy, hx)
    # cos/sin of phi_h without trigonometry; phi_h = 0 where h is the normal
    has_az = sin_h > 0
    sin_s = jnp.where(has_az, sin_h, 1.0)
    cp = jnp.where(has_az, hx / sin_s, 1.0)
    sp = jnp.where(has_az, hy / sin_s, 0.0)
    x, y, z = wi[..., 0], wi[..., 1], wi[..., 2]
    # rotate by -phi_h about z
    x1 = x * cp + y * sp
    y1 = -x * sp + y * cp
    # rotate by -theta_h about y (cos = hz, sin = sin_h)
    dx = x1 * hz - z * sin_h
    dz = x1 * sin_h + z * hz
    theta_d = safe_atan2(safe_sqrt(dx * dx + y1 * y1), dz)
    phi_d = safe_atan2(y1, dx)
    return theta_h, phi_h, theta_d, phi_d


def half_diff_to_directions(
    theta_h, phi_h, theta_d, phi_d
) -> tuple[Float[Array, "*batch 3"], Float[Array, "*batch 3"]]:
    """Inverse of :func:`half_diff_coords`: (wi, wo) as unit vectors [*batch, 3]."""
    theta_h, phi_h, theta_d, phi_d = jnp.broadcast_arrays(*(jnp.asarray(v) for v in (theta_h, phi_h, theta_d, phi_d)))
    st, ct = jnp.sin(theta_d), jnp.cos(theta_d)
    d = (st * jnp.cos(phi_d), st * jnp.sin(phi_d), ct)
    sh, ch = jnp.sin(theta_h), jnp.cos(theta_h)
    sp, cp = jnp.sin(phi_h), jnp.cos(phi_h)
    # rotate by +theta_h about y, then by +phi_h about z
    x1 = d[0] * ch + d[2] * sh
    z1 = -d[0] * sh + d[2] * ch
    wi = jnp.stack([x1 * cp - d[1] * sp, x1 * sp + d[1] * cp, z1], axis=-1)
    h = jnp.stack([sh * cp, sh * sp, ch], axis=-1)
    wo = 2.0 * dot(wi, h) * h - wi
    return wi, wo


def _continuous_coords(wi, wo):
    """Bin coordinates (u_h, u_d, u_p) in units of bins, MERL's mappings before truncation."""
    theta_h, _, theta_d, phi_d = half_diff_coords(wi, wo)
    u_h = safe_sqrt(theta_h / (jnp.pi / 2)) * MERL_RES[0]  # the format's square-root theta_h bins
    u_d = theta_d / (jnp.pi / 2) * MERL_RES[1]
    phi_d = jnp.where(phi_d < 0, phi_d + jnp.pi, phi_d)  # reciprocity: phi_d ~ phi_d + pi
    u_p = phi_d / jnp.pi * MERL_RES[2]
    return u_h, u_d, u_p


def merl_index(wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]):
    """(i_h, i_d, i_p) integer bin indices of MERL's lookup (BRDFRead.cpp:
    theta_half_index, theta_diff_index, phi_diff_index), clamped to the table."""
    u_h, u_d, u_p = _continuous_coords(wi, wo)
    i_h = jnp.clip(jnp.floor(u_h), 0, MERL_RES[0] - 1).astype(jnp.int32)
    i_d = jnp.clip(jnp.floor(u_d), 0, MERL_RES[1] - 1).astype(jnp.int32)
    i_p = jnp.clip(jnp.floor(u_p), 0, MERL_RES[2] - 1).astype(jnp.int32)
    return i_h, i_d, i_p


def merl_bin_centers(dtype=jnp.float64):
    """Angles (theta_h [90], theta_d [90], phi_d [180]) at the centres of the bins in
    the format's own mapping: theta_h = ((i + 1/2)/90)^2 pi/2 (square-root bins)."""
    i = (jnp.arange(MERL_RES[0], dtype=dtype) + 0.5) / MERL_RES[0]
    j = (jnp.arange(MERL_RES[1], dtype=dtype) + 0.5) / MERL_RES[1]
    k = (jnp.arange(MERL_RES[2], dtype=dtype) + 0.5) / MERL_RES[2]
    return i * i * (jnp.pi / 2), j * (jnp.pi / 2), k * jnp.pi


def tabulate_merl(model, dtype=jnp.float64, chunk: int = 90) -> Float[Array, "3 90 90 180"]:
    """Evaluate an isotropic model (parameters 0-d or [C] with C = 1 or 3) at the
    MERL bin centres (phi_h = 0), as a table [3, 90, 90, 180] of f_r in 1/sr."""
    th, td, pd = merl_bin_centers(dtype)

    @eqx.filter_jit
    def rows(m, th_rows):
        t_h, t_d, p_d = jnp.meshgrid(th_rows, td, pd, indexing="ij")
        wi, wo = half_diff_to_directions(t_h, jnp.zeros_like(t_h), t_d, p_d)
        f = jax.vmap(m)(wi.reshape(-1, 3), wo.reshape(-1, 3))
        f = jnp.broadcast_to(f, (f.shape[0], 3))
        return f.reshape(t_h.shape + (3,))

    parts = [rows(model, th[s : s + chunk]) for s in range(0, MERL_RES[0], chunk)]
    return jnp.moveaxis(jnp.concatenate(parts, axis=0), -1, 0)


def read_merl(path: str | os.PathLike, interpolation: str = "nearest") -> MERL:
    """Read a MERL .binary file into a :class:`MERL` model (values in 1/sr, scales applied)."""
    path = Path(path)
    size = path.stat().st_size
    if size < _HEADER_BYTES:
        raise ValueError(f"read_merl({path}): file has {size} bytes, too short for the 12-byte header")
    with open(path, "rb") as f:
        dims = np.frombuffer(f.read(_HEADER_BYTES), dtype="<i4")
        if int(np.prod(dims.astype(np.int64))) != _N:
            raise ValueError(f"read_merl({path}): header dims {tuple(int(d) for d in dims)}, expected {MERL_RES}")
        if size != _FILE_BYTES:
            raise ValueError(f"read_merl({path}): file has {size} bytes, expected {_FILE_BYTES} (12 + 8 x 3 x {_N})")
        data = np.frombuffer(f.read(), dtype="<f8").reshape((3,) + MERL_RES)
    table = data * np.asarray(MERL_SCALE)[:, None, None, None]
    return MERL(table, interpolation=interpolation)


class MERL(AbstractBRDF):
    per_sample: ClassVar[bool] = False  # one table for every sample
    """A tabulated isotropic BRDF on MERL's grid (Matusik et al. 2003, "A
    data-driven reflectance model"). ``table`` [3, 90, 90, 180] holds f_r in 1/sr;
    missing (negative) entries evaluate to 0.

    ``"nearest"`` reproduces MERL's reference lookup exactly (piecewise constant:
    its gradient with respect to directions is 0); ``"linear"`` interpolates
    trilinearly between bin centres (phi_d periodic with period pi, theta axes
    clamped), differentiable almost everywhere. Reciprocal by construction
    (the parameterisation is symmetric); energy conservation is the data's.
    """

    table: Float[Array, "3 90 90 180"]
    interpolation: str = eqx.field(static=True)

    def __init__(self, table, interpolation: str = "nearest"):
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"MERL: interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
        t = jnp.asarray(table)
        if t.shape != (3,) + MERL_RES:
            raise ValueError(f"MERL: table must have shape (3, 90, 90, 180), got {t.shape}")
        self.table = t
        self.interpolation = interpolation

    def __call__(self, wi: Float[Array, "*batch 3"], wo: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """Tabulated f_r in 1/sr, shape [*batch, 3]; 0 below the horizon."""
        wi, wo = check_directions("MERL", wi, wo)
        active = (cos_theta(wi) > 0) & (cos_theta(wo) > 0)
        table = jnp.maximum(self.table, 0.0).astype(working_float(wi.dtype))
        flat = table.reshape(3, -1)
        if self.interpolation == "nearest":
            i_h, i_d, i_p = merl_index(wi, wo)
            idx = (i_h * MERL_RES[1] + i_d) * MERL_RES[2] + i_p
            vals = jnp.moveaxis(flat[:, idx], 0, -1)
        else:
            u_h, u_d, u_p = _continuous_coords(wi, wo)
            # bin centres sit at integer + 1/2
            coords = (u_h - 0.5, u_d - 0.5, u_p - 0.5)
            vals = 0.0
            base = [jnp.floor(c) for c in coords]
            frac = [c - b for c, b in zip(coords, base, strict=True)]
            for corner in range(8):
                bits = [(corner >> a) & 1 for a in range(3)]
                w = 1.0
                ids = []
                for a in range(3):
                    w = w * (frac[a] if bits[a] else 1.0 - frac[a])
                    i = base[a].astype(jnp.int32) + bits[a]
                    i = jnp.mod(i, MERL_RES[a]) if a == 2 else jnp.clip(i, 0, MERL_RES[a] - 1)
                    ids.append(i)
                idx = (ids[0] * MERL_RES[1] + ids[1]) * MERL_RES[2] + ids[2]
                vals = vals + w[..., None] * jnp.moveaxis(flat[:, idx], 0, -1)
        return jnp.where(active, vals, 0.0)

    def fittable(self) -> dict[str, ParamSpec]:
        """None: measured data are not fitted."""
        return {}
