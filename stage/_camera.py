"""Pinhole cameras in the OpenCV convention.

A world point X maps to camera coordinates X_c = R X + t (x right, y down,
z forward) and to pixel (u, v) = (fx x/z + cx, fy y/z + cy); pixel centres are
at integer + 0.5. Lengths in millimetres.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from brdf import safe_div, safe_normalize


class Camera(eqx.Module):
    """Pinhole camera: intrinsics ``K`` [3, 3], rotation ``R`` [3, 3] and
    translation ``t`` [3] (world to camera), and the image size in pixels."""

    K: Float[Array, "3 3"]
    R: Float[Array, "3 3"]
    t: Float[Array, " 3"]
    width: int = eqx.field(static=True)
    height: int = eqx.field(static=True)

    def __check_init__(self):
        if self.K.shape != (3, 3) or self.R.shape != (3, 3) or self.t.shape != (3,):
            raise ValueError(f"Camera needs K [3,3], R [3,3], t [3]; got {self.K.shape}, {self.R.shape}, {self.t.shape}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"Camera resolution must be positive, got {self.width}x{self.height}")

    @property
    def center(self) -> Float[Array, " 3"]:
        """Camera centre in world coordinates, -R^T t."""
        return -self.R.T @ self.t

    def to_camera(self, points: Float[Array, "*batch 3"]) -> Float[Array, "*batch 3"]:
        points = jnp.asarray(points)
        return points @ self.R.T + self.t.reshape((1,) * (points.ndim - 1) + (3,))

    def project(self, points: Float[Array, "*batch 3"]) -> tuple[Float[Array, "*batch 2"], Float[Array, " *batch"]]:
        """Pixel coordinates and depth (camera z, mm) of world points."""
        xc = self.to_camera(points)
        z = xc[..., 2]
        uvw = xc @ self.K.T
        pix = safe_div(uvw[..., :2], uvw[..., 2:3])
        return pix, z

    def rays(self, pixels: Float[Array, "*batch 2"]) -> tuple[Float[Array, " 3"], Float[Array, "*batch 3"]]:
        """Origin (the camera centre) and unit world directions through pixels."""
        pixels = jnp.asarray(pixels)
        ones = jnp.ones(pixels.shape[:-1] + (1,), pixels.dtype)
        d_cam = jnp.concatenate([pixels, ones], axis=-1) @ jnp.linalg.inv(self.K).T
        return self.center, safe_normalize(d_cam @ self.R)


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
