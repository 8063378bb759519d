"""Pinhole and orthographic cameras in the OpenCV convention.

A world point X maps to camera coordinates X_c = R X + t (x right, y down,
z forward) and to pixel (u, v) = (fx x/z + cx, fy y/z + cy) for a pinhole,
(fx x + cx, fy y + cy) for an orthographic camera (fx, fy in pixels per mm);
pixel centres are at integer + 0.5. Lengths in millimetres.

Camera files (``save_cameras`` / ``load_cameras``) are JSON:
``{"convention": "opencv", "units": "mm", "cameras": [{"name", "model":
"pinhole"|"orthographic", "width", "height", "K": 3x3, "R": 3x3, "t": 3}]}``.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from brdf import safe_div, safe_normalize


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

    def __check_init__(self):
        if self.K.shape != (3, 3) or self.R.shape != (3, 3) or self.t.shape != (3,):
            raise ValueError(f"Camera needs K [3,3], R [3,3], t [3]; got {self.K.shape}, {self.R.shape}, {self.t.shape}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"Camera resolution must be positive, got {self.width}x{self.height}")

    @property
    def center(self) -> Float[Array, " 3"]:
        """Camera centre in world coordinates, -R^T t (for an orthographic camera,
        the centre of its image plane)."""
        return -self.R.T @ self.t

    @property
    def forward(self) -> Float[Array, " 3"]:
        """Unit viewing direction (camera +z) in world coordinates."""
        return self.R[2]

    def to_camera(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """World points (mm) to camera coordinates X_c = R X + t (mm)."""
        points = jnp.asarray(points)
        return points @ self.R.T + self.t.reshape((1,) * (points.ndim - 1) + (3,))

    def project(self, points: Float[Array, "*batch 3"]) -> tuple[Float[Array, "*batch 2"], Float[Array, " *batch"]]:
        """Pixel coordinates and depth (camera z, mm) of world points."""
        xc = self.to_camera(points)
        z = xc[..., 2]
        if self.orthographic:
            xy1 = jnp.concatenate([xc[..., :2], jnp.ones_like(xc[..., 2:3])], axis=-1)
            return (xy1 @ self.K.T)[..., :2], z
        uvw = xc @ self.K.T
        pix = safe_div(uvw[..., :2], uvw[..., 2:3])
        return pix, z

    def rays(self, pixels: Float[Array, "*batch 2"]) -> tuple[Float[Array, "*batch 3"], Float[Array, "*batch 3"]]:
        """Origins and unit world directions of the rays through pixels. A pinhole
        returns its centre [3] as the one origin; an orthographic camera returns
        one origin per pixel [*batch, 3] on its image plane (camera z = 0)."""
        pixels = jnp.asarray(pixels)
        ones = jnp.ones(pixels.shape[:-1] + (1,), pixels.dtype)
        d_cam = jnp.concatenate([pixels, ones], axis=-1) @ jnp.linalg.inv(self.K).T
        if self.orthographic:
            xc = jnp.concatenate([d_cam[..., :2], jnp.zeros_like(ones)], axis=-1)
            origins = (xc - self.t.reshape((1,) * (xc.ndim - 1) + (3,))) @ self.R
            return origins, jnp.broadcast_to(self.forward, origins.shape)
        return self.center, safe_normalize(d_cam @ self.R)

    def view_directions(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
        """Unit world directions from points toward the camera (wo before the
        change to the shading frame): toward the centre for a pinhole, -forward
        for an orthographic camera."""
        points = jnp.asarray(points)
        if self.orthographic:
            return jnp.broadcast_to(-self.forward, points.shape)
        return safe_normalize(self.center.reshape((1,) * (points.ndim - 1) + (3,)) - points)

    def pixel_area(self, points: Float[Array, "*batch 3"]) -> Float[Array, " *batch"]:
        """Area (mm^2) of one pixel's footprint on the plane through each point
        perpendicular to the optical axis: z^2 / (fx fy) (pinhole), 1 / (fx fy)
        (orthographic)."""
        z = self.to_camera(points)[..., 2]
        inv = 1.0 / (self.K[0, 0] * self.K[1, 1])
        return inv * jnp.ones_like(z) if self.orthographic else inv * z * z


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
                width: int = 512, height: int = 512, start_deg: float = 0.0, arc_deg: float = 360.0) -> tuple[Camera, ...]:
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


def _atomic_write_text(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_cameras(path, cameras, names=None) -> Path:
    """Write cameras to a JSON file (module docstring format), atomically: a
    temporary file in the same folder, then ``os.replace``."""
    cameras = (cameras,) if isinstance(cameras, Camera) else tuple(cameras)
    path = Path(path)
    names = list(names) if names is not None else [f"cam{i:03d}" for i in range(len(cameras))]
    if len(names) != len(cameras):
        raise ValueError(f"save_cameras: {len(names)} names for {len(cameras)} cameras")
    doc = {"convention": "opencv", "units": "mm", "cameras": [
        {"name": nm, "model": "orthographic" if c.orthographic else "pinhole", "width": c.width, "height": c.height,
         "K": np.asarray(c.K, np.float64).tolist(), "R": np.asarray(c.R, np.float64).tolist(),
         "t": np.asarray(c.t, np.float64).tolist()} for nm, c in zip(names, cameras)]}
    _atomic_write_text(path, json.dumps(doc, indent=1))
    return path


def load_cameras(path) -> tuple[Camera, ...]:
    """Read cameras written by ``save_cameras`` (OpenCV K, R, t in mm). Raises
    ValueError naming the file, the camera and the field when one is missing or
    malformed (R must be a rotation to 1e-4)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"camera file not found: {path}")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(doc, dict) or not isinstance(doc.get("cameras"), list) or not doc["cameras"]:
        raise ValueError(f"{path}: expected an object with a non-empty 'cameras' list")
    out = []
    for i, c in enumerate(doc["cameras"]):
        where = f"{path}: camera {i}"
        try:
            K, R, t = (np.asarray(c[k], np.float64) for k in ("K", "R", "t"))
            w, h = int(c["width"]), int(c["height"])
        except KeyError as exc:
            raise ValueError(f"{where}: missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: malformed field ({exc})") from None
        for name, a, shp in (("K", K, (3, 3)), ("R", R, (3, 3)), ("t", t, (3,))):
            if a.shape != shp or not np.all(np.isfinite(a)):
                raise ValueError(f"{where}: field {name!r} must be finite with shape {shp}, got {a.shape}")
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
            raise ValueError(f"{where}: field 'R' is not a rotation matrix")
        model = c.get("model", "pinhole")
        if model not in ("pinhole", "orthographic"):
            raise ValueError(f"{where}: field 'model' must be 'pinhole' or 'orthographic', got {model!r}")
        out.append(Camera(K=jnp.asarray(K, jnp.float32), R=jnp.asarray(R, jnp.float32), t=jnp.asarray(t, jnp.float32),
                          width=w, height=h, orthographic=model == "orthographic"))
    return tuple(out)
