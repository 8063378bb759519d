"""Other environment-map parameterisations and conversions to and from lat-long.

All in the light-stage frame (x right, y up, z toward the main camera), images
with row 0 at the top:

* Angular map (Debevec's light-probe format, "Rendering Synthetic Objects into
  Real Scenes", SIGGRAPH 1998, and his probe gallery's definition): a disk in
  an N x N image; with (u, v) in [-1, 1]^2 (u right, v up) and r = |(u, v)|,
  the direction is at angle pi r from the view direction -z:
  ``d = (sin(pi r) u / r, sin(pi r) v / r, -cos(pi r))``. The centre is -z, the
  rim is +z. Solid angle per unit image area: pi sin(pi r) / r.
* Mirror ball: an orthographic photograph, from +z, of a mirrored sphere
  filling the image; the pixel with normal n = (u, v, sqrt(1 - r^2)) sees the
  reflection of the view ray, ``d = (2 n_z u, 2 n_z v, 2 n_z^2 - 1)``. The
  centre sees +z (behind the camera), the rim -z. Solid angle per unit image
  area is exactly 4 (dOmega = sin t dt dphi and r = sin(t / 2)).
* Cube map: six N x N faces in OpenGL order (+x, -x, +y, -y, +z, -z) with the
  OpenGL face orientations (GL spec, "Cube Map Texture Selection"); the
  per-pixel solid angle is exact (area of a spherical rectangle).

Conversions resample bilinearly at the target's pixel centres (no
prefiltering: convert to a similar or higher resolution, or downsample after).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from ._latlong import EnvMap, latlong_directions, sample_latlong

__all__ = [
    "angular_directions",
    "angular_solid_angles",
    "angular_to_latlong",
    "cubemap_directions",
    "cubemap_solid_angles",
    "cubemap_to_latlong",
    "direction_to_angular",
    "direction_to_cubemap",
    "direction_to_mirrorball",
    "latlong_to_angular",
    "latlong_to_cubemap",
    "latlong_to_mirrorball",
    "mirrorball_directions",
    "mirrorball_solid_angles",
    "mirrorball_to_latlong",
    "sample_angular",
    "sample_cubemap",
    "sample_mirrorball",
]


def _float(dtype):
    return jnp.dtype(dtype) if dtype is not None else jnp.zeros(()).dtype


def _disk_uv(size: int, dt) -> tuple[Array, Array]:
    """u (right) and v (up) in [-1, 1] at pixel centres of a size x size image."""
    c = (jnp.arange(size, dtype=dt) + 0.5) / size * 2 - 1
    v, u = jnp.meshgrid(-c, c, indexing="ij")
    return u, v


def _uv_to_pixel(u: Array, v: Array, size: int) -> tuple[Array, Array]:
    """Continuous (row, col) pixel coordinates (pixel centres at integers)."""
    return (1 - v) / 2 * size - 0.5, (u + 1) / 2 * size - 0.5


def _bilinear(img: Array, row: Array, col: Array) -> Array:
    """Bilinear lookup with coordinates clamped to the image (edge pixels extend)."""
    h, w = img.shape[0], img.shape[1]
    row = jnp.clip(row, 0.0, h - 1.0)
    col = jnp.clip(col, 0.0, w - 1.0)
    r0 = jnp.floor(row)
    c0 = jnp.floor(col)
    fr = (row - r0)[..., None]
    fc = (col - c0)[..., None]
    r0i, c0i = r0.astype(jnp.int32), c0.astype(jnp.int32)
    r1i, c1i = jnp.minimum(r0i + 1, h - 1), jnp.minimum(c0i + 1, w - 1)
    top = img[r0i, c0i] * (1 - fc) + img[r0i, c1i] * fc
    bot = img[r1i, c0i] * (1 - fc) + img[r1i, c1i] * fc
    return top * (1 - fr) + bot * fr


# ------------------------------------------------------------------ angular


@functools.partial(jax.jit, static_argnames=('size', 'dtype'))
def angular_directions(size: int, dtype=None) -> tuple[Float[Array, "N N 3"], Bool[Array, "N N"]]:
    """Directions of the pixel centres of a size x size angular map, and the
    mask of pixels inside the disk (directions outside it are meaningless)."""
    dt = _float(dtype)
    u, v = _disk_uv(size, dt)
    r = jnp.sqrt(u * u + v * v)
    ok = r > 0
    s = jnp.where(ok, jnp.sin(jnp.pi * r) / jnp.where(ok, r, 1), jnp.pi)  # sin(pi r)/r -> pi at 0
    d = jnp.stack([s * u, s * v, -jnp.cos(jnp.pi * r)], axis=-1)
    return d, r <= 1


@functools.partial(jax.jit, static_argnames=('size', 'dtype'))
def angular_solid_angles(size: int, dtype=None) -> Float[Array, "N N"]:
    """Solid angle of each pixel of an angular map (Jacobian at the pixel centre,
    pi sin(pi r) / r times the pixel area; 0 outside the disk). The sum
    approaches 4 pi as size grows (the rim pixels are cut by the disk)."""
    dt = _float(dtype)
    u, v = _disk_uv(size, dt)
    r = jnp.sqrt(u * u + v * v)
    ok = r > 0
    jac = jnp.where(ok, jnp.pi * jnp.sin(jnp.pi * r) / jnp.where(ok, r, 1), jnp.pi**2)
    return jnp.where(r <= 1, jac * (2.0 / size) ** 2, 0.0)


@functools.partial(jax.jit, static_argnames=('size',))
def direction_to_angular(d: Float[ArrayLike, "*batch 3"], size: int) -> tuple[Array, Array]:
    """Continuous (row, col) of direction ``d`` in a size x size angular map."""
    d = jnp.asarray(d)
    n = jnp.sqrt(jnp.sum(d * d, axis=-1))
    z = -d[..., 2] / jnp.where(n > 0, n, 1)
    r = jnp.arccos(jnp.clip(z, -1.0, 1.0)) / jnp.pi
    rho = jnp.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2)
    ok = rho > 0
    s = jnp.where(ok, r / jnp.where(ok, rho, 1), 0.0)
    return _uv_to_pixel(s * d[..., 0], s * d[..., 1], size)


@jax.jit
def sample_angular(img: Float[ArrayLike, "N N C"], d: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch C"]:
    """Bilinear lookup of an angular map in directions ``d``."""
    img = jnp.asarray(img)
    row, col = direction_to_angular(d, img.shape[0])
    return _bilinear(img, row, col)


@functools.partial(jax.jit, static_argnames=('size',))
def latlong_to_angular(env: EnvMap, size: int) -> Float[Array, "N N C"]:
    """Resample a lat-long map as a size x size angular map (0 outside the disk)."""
    d, inside = angular_directions(size, env.radiance.dtype)
    return jnp.where(inside[..., None], sample_latlong(env.radiance, d), 0.0)


@functools.partial(jax.jit, static_argnames=('height',))
def angular_to_latlong(img: Float[ArrayLike, "N N C"], height: int) -> EnvMap:
    """Resample an angular map as a lat-long map of the given height (width 2 x height)."""
    img = jnp.asarray(img)
    return EnvMap(sample_angular(img, latlong_directions(height, 2 * height, img.dtype)))


# --------------------------------------------------------------- mirror ball


@functools.partial(jax.jit, static_argnames=('size', 'dtype'))
def mirrorball_directions(size: int, dtype=None) -> tuple[Float[Array, "N N 3"], Bool[Array, "N N"]]:
    """Reflected directions seen at the pixel centres of a mirror-ball image, and
    the mask of pixels on the ball."""
    dt = _float(dtype)
    u, v = _disk_uv(size, dt)
    r2 = u * u + v * v
    nz = jnp.sqrt(jnp.maximum(1 - r2, 0.0))
    d = jnp.stack([2 * nz * u, 2 * nz * v, 2 * nz * nz - 1], axis=-1)
    return d, r2 <= 1


@functools.partial(jax.jit, static_argnames=('size', 'dtype'))
def mirrorball_solid_angles(size: int, dtype=None) -> Float[Array, "N N"]:
    """Solid angle of each mirror-ball pixel: exactly 4 x its area inside the
    disk (approximated by the pixel-centre test; 0 off the ball)."""
    dt = _float(dtype)
    u, v = _disk_uv(size, dt)
    return jnp.where(u * u + v * v <= 1, 4 * (2.0 / size) ** 2, 0.0).astype(dt)


@functools.partial(jax.jit, static_argnames=('size',))
def direction_to_mirrorball(d: Float[ArrayLike, "*batch 3"], size: int) -> tuple[Array, Array]:
    """Continuous (row, col) of direction ``d`` in a mirror-ball image: the ball's
    normal there is the half vector of ``d`` and the view direction +z. ``d = -z``
    (the rim, a whole circle) maps to the rim's top point."""
    d = jnp.asarray(d)
    n = jnp.sqrt(jnp.sum(d * d, axis=-1, keepdims=True))
    d = d / jnp.where(n > 0, n, 1)
    h = jnp.stack([d[..., 0], d[..., 1], d[..., 2] + 1], axis=-1)  # d + view direction (+z)
    hn = jnp.sqrt(jnp.sum(h * h, axis=-1, keepdims=True))
    ok = hn > 1e-12
    h = h / jnp.where(ok, hn, 1)
    # d = -z: every rim point reflects it; pick the top of the rim (u, v) = (0, 1).
    zero, one = jnp.zeros_like(d[..., 0]), jnp.ones_like(d[..., 0])
    h = jnp.where(ok, h, jnp.stack([zero, one, zero], axis=-1))
    return _uv_to_pixel(h[..., 0], h[..., 1], size)


@jax.jit
def sample_mirrorball(img: Float[ArrayLike, "N N C"], d: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch C"]:
    """Bilinear lookup of a mirror-ball image in directions ``d``."""
    img = jnp.asarray(img)
    row, col = direction_to_mirrorball(d, img.shape[0])
    return _bilinear(img, row, col)


@functools.partial(jax.jit, static_argnames=('size',))
def latlong_to_mirrorball(env: EnvMap, size: int) -> Float[Array, "N N C"]:
    """Resample a lat-long map as a size x size mirror-ball image (0 off the ball)."""
    d, inside = mirrorball_directions(size, env.radiance.dtype)
    return jnp.where(inside[..., None], sample_latlong(env.radiance, d), 0.0)


@functools.partial(jax.jit, static_argnames=('height',))
def mirrorball_to_latlong(img: Float[ArrayLike, "N N C"], height: int) -> EnvMap:
    """Resample a mirror-ball image as a lat-long map. Directions near -z come from
    the ball's compressed rim and are blurred (the ball's resolution there is ~0)."""
    img = jnp.asarray(img)
    return EnvMap(sample_mirrorball(img, latlong_directions(height, 2 * height, img.dtype)))


# ------------------------------------------------------------------ cube map


def _face_dirs(s: Array, t: Array) -> Array:
    """[6, ..., 3] directions (not normalised) of face coordinates s, t in OpenGL order."""
    one = jnp.ones_like(s)
    return jnp.stack(
        [
            jnp.stack([one, -t, -s], -1),  # +x
            jnp.stack([-one, -t, s], -1),  # -x
            jnp.stack([s, one, t], -1),  # +y
            jnp.stack([s, -one, -t], -1),  # -y
            jnp.stack([s, -t, one], -1),  # +z
            jnp.stack([-s, -t, -one], -1),  # -z
        ]
    )


@functools.partial(jax.jit, static_argnames=('size', 'dtype'))
def cubemap_directions(size: int, dtype=None) -> Float[Array, "6 N N 3"]:
    """Unit directions of the pixel centres of the six faces (OpenGL order and orientation)."""
    dt = _float(dtype)
    c = (jnp.arange(size, dtype=dt) + 0.5) / size * 2 - 1
    t, s = jnp.meshgrid(c, c, indexing="ij")  # row -> t, column -> s
    d = _face_dirs(s, t)
    return d / jnp.linalg.norm(d, axis=-1, keepdims=True)


@functools.partial(jax.jit, static_argnames=('size', 'dtype'))
def cubemap_solid_angles(size: int, dtype=None) -> Float[Array, "6 N N"]:
    """Exact solid angle of each cube-map pixel (sums to 4 pi): for the face
    rectangle [x0, x1] x [y0, y1] at distance 1,
    A(x0,y0) - A(x0,y1) - A(x1,y0) + A(x1,y1) with A(x, y) = atan2(x y, sqrt(x^2 + y^2 + 1))."""
    dt = _float(dtype)
    e = jnp.arange(size + 1, dtype=dt) / size * 2 - 1
    y, x = jnp.meshgrid(e, e, indexing="ij")
    a = jnp.arctan2(x * y, jnp.sqrt(x * x + y * y + 1))
    face = a[:-1, :-1] - a[1:, :-1] - a[:-1, 1:] + a[1:, 1:]
    return jnp.broadcast_to(jnp.abs(face)[None], (6, size, size))


@functools.partial(jax.jit, static_argnames=('size',))
def direction_to_cubemap(d: Float[ArrayLike, "*batch 3"], size: int) -> tuple[Array, Array, Array]:
    """``(face, row, col)`` of direction ``d``: face index (OpenGL order) and
    continuous pixel coordinates in that face."""
    d = jnp.asarray(d)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    ax, ay, az = jnp.abs(x), jnp.abs(y), jnp.abs(z)
    is_x = (ax >= ay) & (ax >= az)
    is_y = ~is_x & (ay >= az)
    face = jnp.where(is_x, jnp.where(x > 0, 0, 1), jnp.where(is_y, jnp.where(y > 0, 2, 3), jnp.where(z > 0, 4, 5)))
    ma = jnp.where(is_x, ax, jnp.where(is_y, ay, az))
    ma = jnp.where(ma > 0, ma, 1.0)
    # (sc, tc) per face, from the OpenGL cube-map selection table.
    sc = jnp.select([face == 0, face == 1, face == 2, face == 3, face == 4], [-z, z, x, x, x], -x)
    tc = jnp.select([face == 0, face == 1, face == 2, face == 3, face == 4], [-y, -y, z, -z, -y], -y)
    s, t = sc / ma, tc / ma
    return face, (t + 1) / 2 * size - 0.5, (s + 1) / 2 * size - 0.5


@jax.jit
def sample_cubemap(faces: Float[ArrayLike, "6 N N C"], d: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch C"]:
    """Bilinear lookup of a cube map in directions ``d`` (within a face; the
    half-pixel band along face edges is clamped to the face's edge pixels)."""
    faces = jnp.asarray(faces)
    n = faces.shape[1]
    face, row, col = direction_to_cubemap(d, n)
    row = jnp.clip(row, 0.0, n - 1.0)
    col = jnp.clip(col, 0.0, n - 1.0)
    r0 = jnp.floor(row)
    c0 = jnp.floor(col)
    fr = (row - r0)[..., None]
    fc = (col - c0)[..., None]
    r0i, c0i = r0.astype(jnp.int32), c0.astype(jnp.int32)
    r1i, c1i = jnp.minimum(r0i + 1, n - 1), jnp.minimum(c0i + 1, n - 1)
    top = faces[face, r0i, c0i] * (1 - fc) + faces[face, r0i, c1i] * fc
    bot = faces[face, r1i, c0i] * (1 - fc) + faces[face, r1i, c1i] * fc
    return top * (1 - fr) + bot * fr


@functools.partial(jax.jit, static_argnames=('size',))
def latlong_to_cubemap(env: EnvMap, size: int) -> Float[Array, "6 N N C"]:
    """Resample a lat-long map as six size x size cube faces."""
    return sample_latlong(env.radiance, cubemap_directions(size, env.radiance.dtype))


@functools.partial(jax.jit, static_argnames=('height',))
def cubemap_to_latlong(faces: Float[ArrayLike, "6 N N C"], height: int) -> EnvMap:
    """Resample a cube map as a lat-long map of the given height."""
    faces = jnp.asarray(faces)
    return EnvMap(sample_cubemap(faces, latlong_directions(height, 2 * height, faces.dtype)))
