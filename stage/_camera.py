"""Pinhole and orthographic cameras, and their files in the OpenCV convention.

A world point X maps to camera coordinates X_c = R X + t (x right, y down,
z forward), to normalised coordinates (x, y) = (X_c / Z_c, Y_c / Z_c), through
OpenCV's lens distortion (k1, k2, p1, p2, k3; :func:`distort`) and to pixel
(u, v) = K (x_d, y_d, 1) for a pinhole, (fx X_c + cx, fy Y_c + cy) for an
orthographic camera (fx, fy in pixels per mm; no distortion). Lengths in
millimetres.

Pixel centres: a ``Camera``'s K is in continuous image coordinates, where
pixel (i, j) covers [i, i + 1) x [j, j + 1) and the top-left pixel's centre is
(0.5, 0.5) (COLMAP's and pbrt's convention: scaling an image scales K). A
camera *file* follows OpenCV, whose top-left pixel centre is (0, 0): a centred
256-pixel camera has cx = 127.5 in the file and 128 in the ``Camera``.
``camera_from_dict`` and ``camera_to_dict`` convert, by the file's
``convention``: "opencv" (the default: centres at integers) or "colmap"
(centres at integer + 0.5, K as the Camera holds it); any other value is an
error naming the field.

One JSON schema for a camera, shared by camera files, capture folders and map
sets (``camera_to_dict`` / ``camera_from_dict``)::

    {"name": "cam000", "model": "pinhole" | "orthographic", "width": W, "height": H,
     "K": 3x3, "R": 3x3, "t": 3, "distortion": [k1, k2, p1, p2, k3],
     "convention": "opencv", "units": "mm"}

``distortion`` is optional (none) and lists 4 (k1, k2, p1, p2) or 5
coefficients, or is an object with any of those keys (0 when missing);
OpenCV's longer rational and thin-prism models are refused. It is written
only when non-zero.
A camera file (``save_cameras`` / ``load_cameras``) is
``{"convention": "opencv", "units": "mm", "cameras": [camera, ...]}``; a
file-level ``convention`` is the default of its cameras. ``load_cameras`` also
reads a bare list of cameras (a capture folder's ``cameras.json``,
``relight.io.write_capture``), and camera entries without the per-camera
``convention`` / ``units`` keys. Units must be "mm".

Camera files written before this convention was fixed (CHANGELOG, "Unreleased") hold K with the
continuous centres under "opencv": set their ``convention`` to "colmap" to read them as written.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from brdf import safe_div, safe_normalize

from ._atomic import atomic_write_text
from ._files import read_json
from ._mesh import MAX_COORDINATE_MM


class Camera(eqx.Module):
    """Camera: intrinsics ``K`` [3, 3], rotation ``R`` [3, 3] and translation
    ``t`` [3] (world to camera, mm), the image size in pixels, and (static)
    ``orthographic``: False for a pinhole (K in pixels), True for an
    orthographic camera (K's focal entries in pixels per mm)."""

    K: Float[Array, "3 3"]
    R: Float[Array, "3 3"]
    t: Float[Array, " 3"]
    width: int = eqx.field(static=True)
    height: int = eqx.field(static=True)
    orthographic: bool = eqx.field(static=True, default=False)
    dist: Float[Array, " 5"] = eqx.field(default_factory=lambda: jnp.zeros(5, jnp.float32))

    def __check_init__(self):
        if self.K.shape != (3, 3) or self.R.shape != (3, 3) or self.t.shape != (3,) or self.dist.shape != (5,):
            raise ValueError(f"Camera needs K [3,3], R [3,3], t [3], dist [5]; "
                             f"got {self.K.shape}, {self.R.shape}, {self.t.shape}, {self.dist.shape}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"Camera resolution must be positive, got {self.width}x{self.height}")
        if self.width * self.height > MAX_CAMERA_PIXELS:
            raise ValueError(f"Camera resolution {self.width}x{self.height} is above the limit of "
                             f"{MAX_CAMERA_PIXELS} pixels (stage.MAX_CAMERA_PIXELS)")
        try:  # the focal lengths, when K is a concrete array (not a tracer inside jit / vmap)
            fx, fy = float(self.K[0, 0]), float(self.K[1, 1])
        except jax.errors.ConcretizationTypeError:
            return
        if not (np.isfinite(fx) and np.isfinite(fy) and fx > 0 and fy > 0):
            raise ValueError(f"Camera argument 'K': focal lengths fx = {fx}, fy = {fy} must be positive and finite")
        try:
            dist = np.asarray(self.dist, np.float64)
        except jax.errors.TracerArrayConversionError:
            return
        if not np.all(np.isfinite(dist)):
            raise ValueError(f"Camera argument 'dist': coefficients must be finite, got {dist.tolist()}")
        if self.orthographic and np.any(dist != 0):
            raise ValueError("Camera argument 'dist': an orthographic camera takes no lens distortion")

    def crop(self, x0: int, y0: int, width: int, height: int) -> Camera:
        """The window of this camera's image from pixel (``x0``, ``y0``) (column, row of its top-left corner),
        ``width`` x ``height`` pixels, as a camera of its own: the same pose, lens and pixels, the principal
        point moved by (-x0, -y0). A pixel (x, y) of the window is the pixel (x + x0, y + y0) of this image (the
        distortion acts on normalised coordinates, which the shift does not change), so an image can be worked
        on in bands of rows and the bands stacked.

        Args:
            x0, y0: the window's first column and row (integers, inside the image).
            width, height: its size in pixels (>= 1, inside the image).

        Returns:
            The window's ``Camera``.
        """
        for name, v in (("x0", x0), ("y0", y0), ("width", width), ("height", height)):
            if isinstance(v, bool) or int(v) != v:
                raise ValueError(f"Camera.crop: {name} must be an integer, got {v!r}")
        if not (0 <= x0 and 0 <= y0 and width >= 1 and height >= 1 and x0 + width <= self.width
                and y0 + height <= self.height):
            raise ValueError(f"Camera.crop: the window ({x0}, {y0}) + {width}x{height} leaves the "
                             f"{self.width}x{self.height} image")
        K = self.K.at[0, 2].add(-float(x0)).at[1, 2].add(-float(y0))
        return Camera(K=K, R=self.R, t=self.t, width=int(width), height=int(height),
                      orthographic=self.orthographic, dist=self.dist)

    @property
    def center(self) -> Float[Array, " 3"]:
        """Camera centre in world coordinates, -R^T t (for an orthographic camera,
        the centre of its image plane)."""
        return -self.R.T @ self.t

    @property
    def forward(self) -> Float[Array, " 3"]:
        """Unit viewing direction (camera +z) in world coordinates."""
        return self.R[2]

    def _cast(self, x) -> tuple[Array, Array, Array, Array]:
        """``x``, K, R and t in one float dtype: the wider of ``x``'s (an integer
        ``x`` counts as float32) and the camera's, as x64 allows. Explicit, so
        float64 points and a float32 camera work under strict dtype promotion
        (and give float64, as standard promotion would)."""
        x = jnp.asarray(x)
        xdt = x.dtype if jnp.issubdtype(x.dtype, jnp.floating) else np.dtype(np.float32)
        dt = jax.dtypes.canonicalize_dtype(np.promote_types(xdt, self.K.dtype))
        return x.astype(dt), self.K.astype(dt), self.R.astype(dt), self.t.astype(dt)

    @eqx.filter_jit
    def to_camera(self, points: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """World points (mm) to camera coordinates X_c = R X + t (mm)."""
        points, _, R, t = self._cast(points)
        return points @ R.T + t.reshape((1,) * (points.ndim - 1) + (3,))

    @eqx.filter_jit
    def project(self, points: Float[ArrayLike, "*batch 3"]) -> tuple[Float[Array, "*batch 2"], Float[Array, " *batch"]]:
        """Pixel coordinates and depth (camera z, mm) of world points, through the lens distortion
        (:func:`distort`). A point beyond the distortion's monotonic range (where the polynomial folds back
        into the image) maps to (-1, -1), outside every image."""
        xc = self.to_camera(points)
        _, K, _, _ = self._cast(xc)
        z = xc[..., 2]
        if self.orthographic:
            xy1 = jnp.concatenate([xc[..., :2], jnp.ones_like(xc[..., 2:3])], axis=-1)
            return (xy1 @ K.T)[..., :2], z
        xy, ok = distort(safe_div(xc[..., :2], xc[..., 2:3]), self.dist.astype(xc.dtype))
        xy1 = jnp.concatenate([xy, jnp.ones_like(xy[..., :1])], axis=-1)
        pix = jnp.where(ok[..., None], (xy1 @ K.T)[..., :2], -1.0)
        return pix, z

    def rays(self, pixels: Float[ArrayLike, "*batch 2"]) -> tuple[Float[Array, "*origin 3"], Float[Array, "*batch 3"]]:
        """Origins and unit world directions of the rays through pixels. A pinhole
        returns its centre [3] as the one origin; an orthographic camera returns
        one origin per pixel [*batch, 3] on its image plane (camera z = 0)."""
        pixels, K, R, t = self._cast(pixels)
        ones = jnp.ones(pixels.shape[:-1] + (1,), pixels.dtype)
        d_cam = jnp.concatenate([pixels, ones], axis=-1) @ jnp.linalg.inv(K).T
        if not (self.orthographic or _is_zero(self.dist)):
            d_cam = jnp.concatenate([undistort(d_cam[..., :2], self.dist.astype(d_cam.dtype)), ones], axis=-1)
        if self.orthographic:
            xc = jnp.concatenate([d_cam[..., :2], jnp.zeros_like(ones)], axis=-1)
            origins = (xc - t.reshape((1,) * (xc.ndim - 1) + (3,))) @ R
            return origins, jnp.broadcast_to(R[2], origins.shape)
        return -R.T @ t, safe_normalize(d_cam @ R)

    @eqx.filter_jit
    def view_directions(self, points: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """Unit world directions from points toward the camera (wo before the
        change to the shading frame): toward the centre for a pinhole, -forward
        for an orthographic camera."""
        points, _, R, t = self._cast(points)
        if self.orthographic:
            return jnp.broadcast_to(-R[2], points.shape)
        return safe_normalize((-R.T @ t).reshape((1,) * (points.ndim - 1) + (3,)) - points)

    @eqx.filter_jit
    def pixel_area(self, points: Float[ArrayLike, "*batch 3"]) -> Float[Array, " *batch"]:
        """Area (mm^2) of one pixel's footprint on the plane through each point
        perpendicular to the optical axis: z^2 / (fx fy) (pinhole), 1 / (fx fy)
        (orthographic)."""
        z = self.to_camera(points)[..., 2]
        _, K, _, _ = self._cast(z)
        inv = 1.0 / (K[0, 0] * K[1, 1])
        return inv * jnp.ones_like(z) if self.orthographic else inv * z * z


def _is_zero(a) -> bool:
    """Whether ``a`` is a concrete all-zero array (False for a tracer): lets eager code skip a no-op."""
    try:
        return not np.any(np.asarray(a))
    except jax.errors.TracerArrayConversionError:
        return False


# Fixed-point iterations of undistort: OpenCV's undistortPoints runs 5 by default; 20 bring a 10%
# barrel distortion at the image corner to float32 precision.
UNDISTORT_ITERATIONS = 20


def distort(xy: Float[Array, "*batch 2"], dist: Float[Array, " 5"]) -> tuple[Float[Array, "*batch 2"], Array]:
    """OpenCV's lens distortion (Brown-Conrady, ``cv2.projectPoints``): normalised camera coordinates
    (x, y) = (X/Z, Y/Z) to distorted ones, x_d = x L + 2 p1 x y + p2 (r^2 + 2 x^2),
    y_d = y L + p1 (r^2 + 2 y^2) + 2 p2 x y with L = 1 + k1 r^2 + k2 r^4 + k3 r^6.

    Args:
        xy: normalised coordinates [..., 2] (unitless).
        dist: (k1, k2, p1, p2, k3), OpenCV's order.

    Returns:
        ``(xy_d, ok)``: the distorted coordinates, and False where the radial map r L(r) has stopped
        increasing (d(r L)/dr = 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6 <= 0): there the polynomial folds points
        from outside the field of view back into it, and a caller must not trust the pixel.

    References:
        Brown 1966, "Decentering distortion of lenses"; the OpenCV calib3d documentation (pinhole model).
    """
    k1, k2, p1, p2, k3 = (dist[i] for i in range(5))
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    ok = 1 + r2 * (3 * k1 + r2 * (5 * k2 + r2 * 7 * k3)) > 0
    return jnp.stack([xd, yd], axis=-1), ok


def undistort(xy_d: Float[Array, "*batch 2"], dist: Float[Array, " 5"]) -> Float[Array, "*batch 2"]:
    """The inverse of :func:`distort` by fixed-point iteration (as ``cv2.undistortPoints``):
    x <- (x_d - tangential(x)) / L(x), UNDISTORT_ITERATIONS times from x = x_d. Exact for zero
    distortion; within the monotonic range it converges for the distortions of real lenses.

    Args:
        xy_d: distorted normalised coordinates [..., 2].
        dist: (k1, k2, p1, p2, k3).

    Returns:
        The undistorted normalised coordinates [..., 2].
    """
    k1, k2, p1, p2, k3 = (dist[i] for i in range(5))

    def step(_, xy):
        x, y = xy[..., 0], xy[..., 1]
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        tx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
        ty = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
        inv = safe_div(jnp.ones_like(radial), radial)
        return jnp.stack([(xy_d[..., 0] - tx) * inv, (xy_d[..., 1] - ty) * inv], axis=-1)

    return jax.lax.fori_loop(0, UNDISTORT_ITERATIONS, step, xy_d)


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), fov_deg: float = 30.0,
            width: int = 512, height: int = 512) -> Camera:
    """A pinhole camera at ``eye`` looking at ``target`` with vertical field of view
    ``fov_deg`` and world ``up`` (stage frame: y up)."""
    eye = np.asarray(eye, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    fwd = target - eye
    if np.linalg.norm(fwd) == 0:
        raise ValueError("camera eye and target coincide")
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("camera 'up' is parallel to the viewing direction")
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    R = np.stack([right, down, fwd])
    t = -R @ eye
    f = 0.5 * height / np.tan(np.deg2rad(fov_deg) / 2)
    K = np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])
    return Camera(K=jnp.asarray(K, jnp.float32), R=jnp.asarray(R, jnp.float32),
                  t=jnp.asarray(t, jnp.float32), width=int(width), height=int(height))


def orthographic(eye, target=(0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0), extent_mm: float = 300.0,
                 width: int = 512, height: int = 512) -> Camera:
    """An orthographic camera whose image plane passes through ``eye`` facing
    ``target``, covering ``extent_mm`` (mm) vertically (square pixels)."""
    if not extent_mm > 0:
        raise ValueError(f"orthographic extent_mm must be > 0, got {extent_mm}")
    cam = look_at(eye, target, up, 30.0, width, height)
    s = height / float(extent_mm)
    K = np.array([[s, 0, width / 2], [0, s, height / 2], [0, 0, 1.0]])
    return Camera(K=jnp.asarray(K, jnp.float32), R=cam.R, t=cam.t, width=int(width), height=int(height),
                  orthographic=True)


def camera_ring(n: int, radius: float, elevation_mm: float = 0.0, target=(0.0, 0.0, 0.0), fov_deg: float = 30.0,
                width: int = 512, height: int = 512, start_deg: float = 0.0,
                arc_deg: float = 360.0) -> tuple[Camera, ...]:
    """``n`` pinhole cameras on a horizontal ring of ``radius`` (mm) about the y
    axis at height ``elevation_mm`` (mm), all looking at ``target`` — the
    multi-view layout of face-scanning domes. Camera k sits at azimuth
    start_deg + k * arc_deg / n (a full ring) or spread over the arc with both
    ends included (arc_deg < 360); azimuth 0 is +z (the main camera), 90 is +x.
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"camera_ring needs n >= 1 cameras, got {n}")
    if not radius > 0:
        raise ValueError(f"camera_ring radius must be > 0 mm, got {radius}")
    if arc_deg >= 360.0 or n == 1:
        az = np.deg2rad(start_deg + np.arange(n) * arc_deg / n)
    else:
        az = np.deg2rad(start_deg + np.linspace(0.0, arc_deg, n))
    tgt = np.asarray(target, np.float64)
    eyes = np.stack([radius * np.sin(az), np.full(n, elevation_mm), radius * np.cos(az)], axis=1) + tgt * [1, 0, 1]
    return tuple(look_at(e, tgt, fov_deg=fov_deg, width=width, height=height) for e in eyes)


# The largest image a camera may declare: 2^28 pixels (16384 x 16384), relight.io's MAX_IMAGE_PIXELS for
# the same reason: a cameras.json saying 100000 x 100000 is refused here, before an image of that size is
# allocated by a renderer or a photo reader.
MAX_CAMERA_PIXELS = 2**28

CONVENTION = "opencv"
# The pixel-centre offset of each accepted file convention: K_camera = K_file + offset on cx and cy.
CONVENTIONS = {"opencv": 0.5, "colmap": 0.0}
UNITS = "mm"
MODELS = ("pinhole", "orthographic")
DISTORTION_KEYS = ("k1", "k2", "p1", "p2", "k3")
# Names other tools give the distortion coefficients, refused in a camera dict rather than ignored.
_DISTORTION_ALIASES = frozenset({"dist", "D", "dist_coeffs", "distCoeffs", "distortion_coefficients",
                                 *DISTORTION_KEYS})
# R must be a rotation to this tolerance: float32 matrices written as float64
# are orthonormal to ~1e-7, so 1e-4 admits them and refuses a scaled or
# sheared matrix.
_ROTATION_TOL = 1e-4
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def camera_to_dict(camera: Camera, name: str | None = None) -> dict:
    """The camera as a JSON-ready dict (module docstring schema; lists of
    float64, so ``json.dumps`` takes it as it is). ``name`` is stored when given."""
    out = {} if name is None else {"name": str(name)}
    K = np.asarray(camera.K, np.float64).copy()
    K[:2, 2] -= CONVENTIONS[CONVENTION]
    out.update({"model": "orthographic" if camera.orthographic else "pinhole", "width": int(camera.width),
                "height": int(camera.height), "K": K.tolist(),
                "R": np.asarray(camera.R, np.float64).tolist(), "t": np.asarray(camera.t, np.float64).tolist(),
                "convention": CONVENTION, "units": UNITS})
    dist = np.asarray(camera.dist, np.float64)
    if np.any(dist != 0):
        out["distortion"] = dist.tolist()
    return out


def camera_from_dict(doc: object, where: str = "camera", convention: str = CONVENTION) -> Camera:
    """A camera from its dict (``camera_to_dict``'s schema; the ``convention`` /
    ``units`` / ``name`` / ``distortion`` keys optional; ``convention`` is the default of
    a dict without its own, module docstring). Raises ValueError starting with
    ``where`` (e.g. ``"cameras.json: camera 2"``) and naming the field when one
    is missing or malformed: K, R, t must be finite with shapes 3x3, 3x3, 3; K
    upper triangular with positive focal lengths and last row [0, 0, 1]; R a
    rotation to 1e-4; width and height positive integers, width x height at
    most ``MAX_CAMERA_PIXELS``; model pinhole or orthographic."""
    if not isinstance(doc, Mapping):
        raise ValueError(f"{where}: expected a JSON object, got {type(doc).__name__}")
    try:
        K, R, t = (np.asarray(doc[k], np.float64) for k in ("K", "R", "t"))
        w, h = doc["width"], doc["height"]
    except KeyError as exc:
        raise ValueError(f"{where}: missing field {exc.args[0]!r}") from None
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: malformed field ({exc})") from None
    # Finite as the camera's float32 too; a rotation's entries are within [-1, 1] (checked before R R^T,
    # which would overflow), a translation within MAX_COORDINATE_MM.
    for name, a, shp, top in (("K", K, (3, 3), _FLOAT32_MAX), ("R", R, (3, 3), _FLOAT32_MAX),
                              ("t", t, (3,), MAX_COORDINATE_MM)):
        if a.shape != shp or not np.all(np.abs(a) <= top):
            raise ValueError(f"{where}: field {name!r} must be finite with shape {shp} and entries within "
                             f"{top:.4g}, got shape {a.shape}")
    if (np.abs(R).max() > 1.0 + _ROTATION_TOL or np.abs(R @ R.T - np.eye(3)).max() > _ROTATION_TOL
            or np.linalg.det(R) < 0):
        raise ValueError(f"{where}: field 'R' is not a rotation matrix (R R^T = I to {_ROTATION_TOL}, det +1)")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ValueError(f"{where}: field 'K' needs positive focal lengths, got fx = {K[0, 0]}, fy = {K[1, 1]}")
    if np.any(K[[1, 2, 2], [0, 0, 1]] != 0) or K[2, 2] != 1:
        raise ValueError(f"{where}: field 'K' must be upper triangular with K[2] = [0, 0, 1], got {K.tolist()}")
    for name, v in (("width", w), ("height", h)):
        number = not isinstance(v, bool) and isinstance(v, (int, float, np.integer, np.floating))
        if not (number and abs(v) < 2**62 and v == int(v) and v > 0):
            raise ValueError(f"{where}: field {name!r} must be a positive integer, got {v!r}")
    if int(w) * int(h) > MAX_CAMERA_PIXELS:
        raise ValueError(f"{where}: image size {int(w)}x{int(h)} is above the limit of {MAX_CAMERA_PIXELS} "
                         "pixels (stage.MAX_CAMERA_PIXELS)")
    model = doc.get("model", "pinhole")
    if model not in MODELS:
        raise ValueError(f"{where}: field 'model' must be 'pinhole' or 'orthographic', got {model!r}")
    offset, dist = _file_frame(doc, where, convention)
    if model == "orthographic" and np.any(dist != 0):
        raise ValueError(f"{where}: field 'distortion' must be zero for an orthographic camera")
    K = K.copy()
    K[:2, 2] += offset
    return Camera(K=jnp.asarray(K, jnp.float32), R=jnp.asarray(R, jnp.float32), t=jnp.asarray(t, jnp.float32),
                  width=int(w), height=int(h), orthographic=model == "orthographic",
                  dist=jnp.asarray(dist, jnp.float32))


def _file_frame(doc: Mapping, where: str, convention: str) -> tuple[float, np.ndarray]:
    """A camera dict's ``units`` (must be mm), pixel-centre offset (by its ``convention``, else
    ``convention``) and distortion (:func:`_distortion_field`)."""
    if "units" in doc and doc["units"] != UNITS:
        raise ValueError(f"{where}: field 'units' must be {UNITS!r}, got {doc['units']!r}")
    misnamed = sorted(k for k in doc if k in _DISTORTION_ALIASES)
    if misnamed:  # a lens recorded under another tool's name would otherwise be dropped without a word
        raise ValueError(f"{where}: field {misnamed[0]!r} is not read; lens distortion goes in 'distortion' "
                         "(OpenCV's [k1, k2, p1, p2, k3])")
    convention = doc.get("convention", convention)
    if not isinstance(convention, str) or convention not in CONVENTIONS:
        raise ValueError(f"{where}: field 'convention' must be one of {sorted(CONVENTIONS)} (\"opencv\": the "
                         f"top-left pixel's centre at (0, 0); \"colmap\": at (0.5, 0.5)), got {convention!r}")
    return CONVENTIONS[convention], _distortion_field(doc.get("distortion"), where)


def _distortion_field(value, where: str) -> np.ndarray:
    """The ``distortion`` field as OpenCV's five (k1, k2, p1, p2, k3): None (zeros), 4 or 5 finite
    coefficients (k3 = 0 when 4), or an object with any of those keys."""
    if value is None:
        return np.zeros(5)
    if isinstance(value, Mapping):
        unknown = sorted(set(value) - set(DISTORTION_KEYS))
        if unknown:
            raise ValueError(f"{where}: field 'distortion' has unknown keys {unknown} (OpenCV's {DISTORTION_KEYS})")
        value = [value.get(k, 0.0) for k in DISTORTION_KEYS]
    try:
        d = np.asarray(value, np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: field 'distortion' must be numbers ({exc})") from None
    if d.size not in (4, 5):
        raise ValueError(f"{where}: field 'distortion' must list OpenCV's [k1, k2, p1, p2(, k3)], got {d.size} "
                         "coefficients; the rational and thin-prism models (8, 12, 14) are not supported")
    if not np.all(np.abs(d) <= _FLOAT32_MAX):
        raise ValueError(f"{where}: field 'distortion' must be finite, got {d.tolist()}")
    return np.concatenate([d, np.zeros(5 - d.size)])


def save_cameras(path, cameras, names=None) -> Path:
    """Write cameras to a JSON camera file (module docstring schema), atomically
    (``stage._atomic``). Names default to cam000, cam001, ..."""
    cameras = (cameras,) if isinstance(cameras, Camera) else tuple(cameras)
    path = Path(path)
    names = list(names) if names is not None else [f"cam{i:03d}" for i in range(len(cameras))]
    if len(names) != len(cameras):
        raise ValueError(f"save_cameras: {len(names)} names for {len(cameras)} cameras")
    doc = {"convention": CONVENTION, "units": UNITS,
           "cameras": [camera_to_dict(c, nm) for nm, c in zip(names, cameras, strict=True)]}
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
    return path


def load_cameras(path) -> tuple[Camera, ...]:
    """Read a camera file: ``save_cameras``'s object, or a bare list of camera
    dicts (a capture folder's ``cameras.json``). Raises FileNotFoundError, or
    ValueError naming the file, the camera and the field when one is missing or
    malformed (see ``camera_from_dict``)."""
    path = Path(path)
    return cameras_from_doc(read_json(path, "camera file"), path)


def cameras_from_doc(doc: object, where: str | Path) -> tuple[Camera, ...]:
    """The cameras of a camera file's parsed JSON (:func:`load_cameras`' forms): its file-level ``units`` and
    ``convention`` checked and passed on as the default of each camera (:func:`camera_from_dict`). ValueError
    starting with ``where`` (the file) and naming the camera and the field."""
    if isinstance(doc, Mapping):
        cams = doc.get("cameras")
        if not isinstance(cams, list) or not cams:
            raise ValueError(f"{where}: expected a non-empty 'cameras' list")
        if "units" in doc and doc["units"] != UNITS:
            raise ValueError(f"{where}: field 'units' must be {UNITS!r}, got {doc['units']!r}")
        convention = doc.get("convention", CONVENTION)
        if not isinstance(convention, str) or convention not in CONVENTIONS:
            raise ValueError(f"{where}: field 'convention' must be one of {sorted(CONVENTIONS)}, got {convention!r}")
    elif isinstance(doc, list) and doc:
        cams, convention = doc, CONVENTION
    else:
        raise ValueError(f"{where}: expected an object with a non-empty 'cameras' list, or a non-empty list of "
                         "cameras")
    return tuple(camera_from_dict(c, f"{where}: camera {i}", convention) for i, c in enumerate(cams))
