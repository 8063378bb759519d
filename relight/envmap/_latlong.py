"""Lat-long (equirectangular) environment maps in the light-stage frame.

Frame: x right, y up, z toward the main camera (the frame of ``stage.Rig``).
A lat-long map of height H and width W = 2H stores radiance arriving *from*
world direction ``d`` at pixel ``(row, col)`` with

    theta = pi (row + 0.5) / H              polar angle from +y (row 0 is the zenith)
    phi   = 2 pi (col + 0.5) / W - pi       azimuth
    d     = (sin theta sin phi, cos theta, -sin theta cos phi)

so the image centre (phi = 0) looks along -z (away from the camera, the view
behind the subject), phi = +pi/2 is +x, and the left/right edges are +z. Seen
from the centre of the sphere the map is not mirrored (right in the image is
right in the world for a viewer facing -z).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from brdf import safe_atan2, safe_div, safe_normalize, safe_sqrt, widest_float

__all__ = [
    "EnvMap",
    "direction_to_latlong",
    "latlong_directions",
    "latlong_solid_angles",
    "load_envmap",
    "rotate_envmap",
    "rotation_matrix",
    "sample_latlong",
    "envmap_integral",
    "envmap_irradiance",
]


def _float_dtype(dtype):
    return jnp.dtype(dtype) if dtype is not None else jnp.zeros(()).dtype


class EnvMap(eqx.Module):
    """A lat-long environment map: radiance ``[H, W, C]`` (C = 3 for RGB), W = 2 H.

    Radiance is in the file's units (relative W sr^-1 m^-2 for light probes).
    A pytree: ``jax.jit``, ``jax.vmap`` and ``jax.grad`` take it as it is.
    """

    radiance: Float[Array, "H W C"]

    def __init__(self, radiance: Float[ArrayLike, "H W C"]):
        radiance = jnp.asarray(radiance)
        if radiance.ndim != 3:
            raise ValueError(f"EnvMap radiance must be [H, W, C] (lat-long), got shape {radiance.shape}")
        h, w, c = radiance.shape
        if w != 2 * h or h == 0:
            raise ValueError(
                f"EnvMap radiance of shape {radiance.shape}: a lat-long map needs width = 2 x height "
                f"(got width {w}, height {h}); convert other layouts with the envmap conversion functions"
            )
        if c == 0:
            raise ValueError("EnvMap radiance needs at least one channel")
        self.radiance = radiance

    @property
    def height(self) -> int:
        return self.radiance.shape[0]

    @property
    def width(self) -> int:
        return self.radiance.shape[1]


@functools.partial(jax.jit, static_argnames=('height', 'width', 'dtype'))
def latlong_directions(height: int, width: int, dtype=None) -> Float[Array, "H W 3"]:
    """Unit world directions of the pixel centres of an ``height x width`` lat-long map
    (see the module docstring for the convention)."""
    dt = _float_dtype(dtype)
    theta = jnp.pi * (jnp.arange(height, dtype=dt) + 0.5) / height
    phi = 2 * jnp.pi * (jnp.arange(width, dtype=dt) + 0.5) / width - jnp.pi
    st, ct = jnp.sin(theta)[:, None], jnp.cos(theta)[:, None]
    sp, cp = jnp.sin(phi)[None, :], jnp.cos(phi)[None, :]
    return jnp.stack(jnp.broadcast_arrays(st * sp, ct * jnp.ones_like(sp), -st * cp), axis=-1)


def _row_solid_angles(height: int, width: int, dt) -> Array:
    """Exact solid angle of one pixel in each row: (2 pi / W)(cos theta_i - cos theta_{i+1}).

    Written as 2 sin((a + b) / 2) sin((b - a) / 2) so rows near the poles keep full
    relative precision (the cosine difference would cancel)."""
    i = jnp.arange(height, dtype=dt)
    half_width = jnp.pi / (2 * height)  # (theta_{i+1} - theta_i) / 2
    mid = jnp.pi * (i + 0.5) / height
    return (2 * jnp.pi / width) * 2 * jnp.sin(mid) * jnp.sin(half_width)


@functools.partial(jax.jit, static_argnames=('height', 'width', 'dtype'))
def latlong_solid_angles(height: int, width: int, dtype=None) -> Float[Array, "H W"]:
    """Solid angle (sr) of every pixel of a lat-long map; sums to 4 pi exactly
    (up to rounding): each row is a spherical zone split into W equal sectors."""
    dt = _float_dtype(dtype)
    return jnp.broadcast_to(_row_solid_angles(height, width, dt)[:, None], (height, width))


def _azimuth(x: Array, w: Array) -> Array:
    """atan2(x, w) with its value at x = w = 0 (the poles) kept as arctan2 gives it
    (pi or 0 by the signs of the zeros, so lookups there are unchanged) and its
    gradient there 0; elsewhere brdf.safe_atan2, whose gradient does not
    underflow next to the poles."""
    ok = (x != 0) | (w != 0)
    return jnp.where(ok, safe_atan2(x, w), jax.lax.stop_gradient(jnp.arctan2(x, w)))


@jax.jit
def direction_to_latlong(d: Float[ArrayLike, "*batch 3"]) -> tuple[Float[Array, "*batch"], Float[Array, "*batch"]]:
    """World direction -> continuous pixel coordinates ``(row, col)`` of a map of
    height 1 and width 1 (i.e. ``v in [0, 1]`` down, ``u in [0, 1)`` right);
    multiply by (H, W) and subtract 0.5 for pixel-centre coordinates.

    ``d`` need not be normalised (zero vectors map to the zenith). Values and
    gradients are finite for every finite ``d``: the polar angle is
    atan2(|d_xz|, d_y) (accurate next to the poles, where acos(d_y / |d|) loses
    half the digits, and with gradient 0 at them, where acos' is infinite); the
    azimuth's gradient at the poles, where it is undefined, is 0; ``d`` is first
    divided by its largest component, so that no square overflows or underflows.
    """
    d = jnp.asarray(d)
    m = jnp.maximum(jnp.maximum(jnp.abs(d[..., 0:1]), jnp.abs(d[..., 1:2])), jnp.abs(d[..., 2:3]))
    d = safe_div(d, m)  # the zero vector stays 0 (gradient 0)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    v = safe_atan2(safe_sqrt(x * x + z * z), y) / jnp.pi
    u = (_azimuth(x, -z) + jnp.pi) / (2 * jnp.pi)
    u = jnp.where(u >= 1.0, u - 1.0, u)
    return v, u


@functools.partial(jax.jit, static_argnames=('method',))
def sample_latlong(
    radiance: Float[ArrayLike, "H W C"], d: Float[ArrayLike, "*batch 3"], method: str = "bilinear"
) -> Float[Array, "*batch C"]:
    """Look up a lat-long map in world directions ``d``.

    ``"bilinear"`` interpolates between pixel centres, wrapping around in
    azimuth and clamping at the poles' first/last row; ``"nearest"`` returns
    the pixel containing ``d`` (the piecewise-constant map the quadrature
    functions integrate).
    """
    img = jnp.asarray(radiance)
    h, w = img.shape[0], img.shape[1]
    v, u = direction_to_latlong(d)
    if method == "nearest":
        row = jnp.clip(jnp.floor(v * h).astype(jnp.int32), 0, h - 1)
        col = jnp.clip(jnp.floor(u * w).astype(jnp.int32), 0, w - 1)
        return img[row, col]
    if method != "bilinear":
        raise ValueError(f"unknown sampling method {method!r}; expected 'bilinear' or 'nearest'")
    y = v * h - 0.5
    x = u * w - 0.5
    y0 = jnp.floor(y)
    x0 = jnp.floor(x)
    fy = (y - y0)[..., None]
    fx = (x - x0)[..., None]
    y0i = y0.astype(jnp.int32)
    x0i = x0.astype(jnp.int32)
    r0, r1 = jnp.clip(y0i, 0, h - 1), jnp.clip(y0i + 1, 0, h - 1)
    c0, c1 = jnp.mod(x0i, w), jnp.mod(x0i + 1, w)
    top = img[r0, c0] * (1 - fx) + img[r0, c1] * fx
    bot = img[r1, c0] * (1 - fx) + img[r1, c1] * fx
    return top * (1 - fy) + bot * fy


@jax.jit
def rotation_matrix(axis: Float[ArrayLike, " 3"], angle: Float[ArrayLike, ""]) -> Float[Array, "3 3"]:
    """Rotation by ``angle`` radians about ``axis`` (right-handed, Rodrigues' formula).

    ``axis`` need not be normalised (any finite length); a zero axis gives the
    identity, with a zero gradient with respect to the axis.
    """
    axis = jnp.asarray(axis)
    # divided by its largest component first, so that |axis|^2 neither overflows nor underflows;
    # the zero axis stays the zero vector (gradient 0)
    k = safe_normalize(safe_div(axis, jnp.max(jnp.abs(axis))))
    kx, ky, kz = k[0], k[1], k[2]
    zero = jnp.zeros_like(kx)
    K = jnp.stack([jnp.stack([zero, -kz, ky]), jnp.stack([kz, zero, -kx]), jnp.stack([-ky, kx, zero])])
    angle = jnp.asarray(angle, K.dtype)
    return jnp.eye(3, dtype=K.dtype) + jnp.sin(angle) * K + (1 - jnp.cos(angle)) * (K @ K)


@functools.partial(jax.jit, static_argnames=('method',))
def rotate_envmap(env: EnvMap, rotation: Float[ArrayLike, "3 3"], method: str = "bilinear") -> EnvMap:
    """The environment rotated by ``rotation`` (light that arrived from ``d``
    now arrives from ``rotation @ d``), resampled on the same lat-long grid.

    Resampling blurs by up to one pixel; for relighting, rotating the rig
    directions instead is exact (``light_weights(env, dirs @ rotation)``,
    see :func:`relight.envmap.rotation_sweep_weights`).
    """
    R = jnp.asarray(rotation, env.radiance.dtype)
    dirs = latlong_directions(env.height, env.width, env.radiance.dtype)
    # new(d) = old(R^T d); with row vectors, (R^T d)^T = d^T R.
    return EnvMap(sample_latlong(env.radiance, dirs @ R, method))


@jax.jit
def envmap_integral(env: EnvMap) -> Float[Array, " C"]:
    """Integral of the (piecewise-constant) map over the sphere, sum L dOmega, per channel
    (units: radiance x sr, i.e. the irradiance it would deliver if all of it
    arrived at normal incidence)."""
    dom = latlong_solid_angles(env.height, env.width, env.radiance.dtype)
    return jnp.sum(env.radiance * dom[..., None], axis=(0, 1))


@functools.partial(jax.jit, static_argnames=('chunk',))
def envmap_irradiance(
    env: EnvMap, normals: Float[ArrayLike, "*batch 3"], chunk: int = 4096
) -> Float[Array, "*batch C"]:
    """Brute-force irradiance E(n) = sum_pixels L(d) max(0, n . d) dOmega (W m^-2)
    on surfaces with unit normals ``normals`` (no occlusion).

    The reference the spherical-harmonic irradiance is checked against; cost is
    O(N H W), chunked over normals so memory stays O(chunk H W / 16).
    """
    normals = jnp.asarray(normals)
    batch = normals.shape[:-1]
    n = normals.reshape(-1, 3)
    dt = widest_float(env.radiance.dtype, n.dtype)
    dirs = latlong_directions(env.height, env.width, dt).reshape(-1, 3)
    dom = latlong_solid_angles(env.height, env.width, dt)[..., None]
    weighted = (env.radiance.astype(dt) * dom).reshape(-1, env.radiance.shape[-1])
    count = n.shape[0]
    chunk = max(1, min(chunk, count))
    pad = (-count) % chunk
    n_p = jnp.concatenate([n.astype(dt), jnp.zeros((pad, 3), dt)]).reshape(-1, chunk, 3)

    def one(nc):
        cos = jnp.maximum(nc @ dirs.T, 0.0)  # [chunk, HW]
        return cos @ weighted

    out = jax.lax.map(one, n_p).reshape(-1, weighted.shape[-1])[:count]
    return out.reshape(*batch, weighted.shape[-1])


def load_envmap(path: str | os.PathLike) -> EnvMap:
    """Read a lat-long environment map from ``.hdr`` (Radiance RGBE), ``.exr`` or ``.pfm``.

    Args:
        path: the map file.

    Returns:
        An ``EnvMap`` with float32 RGB radiance.

    Raises:
        ImageFormatError (a ValueError): naming the file, for an unknown extension, a width that is not twice the
            height, NaN/Inf or negative radiance, or any read error.
    """
    from ..io._errors import ImageFormatError, check_radiance
    from ..io._exr import read_exr
    from ..io._hdr import read_hdr
    from ..io._pfm import read_pfm

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".hdr":
        img = read_hdr(path)
    elif suffix == ".exr":
        img = read_exr(path)
        if img.shape[-1] == 4:
            img = img[..., :3]  # alpha carries no radiance
    elif suffix == ".pfm":
        img = read_pfm(path)
    else:
        raise ImageFormatError(f"{path}: unknown environment map format {suffix!r} (expected .hdr, .exr or .pfm)")
    h, w = img.shape[:2]
    if w != 2 * h:
        raise ImageFormatError(
            f"{path}: environment map is {w}x{h} (width x height); a lat-long map needs width = 2 x height"
        )
    check_radiance(img, path, "environment radiance")
    return EnvMap(np.asarray(img, np.float32))
