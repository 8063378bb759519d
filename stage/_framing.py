"""Cameras that frame a mesh from the front: the telephoto view of the demo,
``relight simulate`` and ``relight render`` (``--camera front``), and a ring of
such views for several-view captures."""

from __future__ import annotations

import numpy as np

from ._camera import Camera, camera_ring, look_at

__all__ = ["FRONT_FOV_DEG", "front_camera", "front_ring"]

# The front camera's field of view: a telephoto lens, so the subject shows little perspective (the bundled head
# fills the frame from 1.3 m).
FRONT_FOV_DEG = 11.0
# The frame's margin around the mesh's bounding box (1.15: 15% of the larger half-extent).
_MARGIN = 1.15


def front_camera(mesh, size: int) -> Camera:
    """A telephoto pinhole camera on +z framing a mesh.

    Args:
        mesh: anything with ``vertices`` [N, 3] in mm (a ``stage.Mesh``, a trimesh).
        size: the image's width and height in pixels.

    Returns:
        A ``Camera`` on the +z axis through the centre of the mesh's bounding box, aimed at that centre, with a
        field of view of ``FRONT_FOV_DEG`` degrees, at the distance where the box's larger half-extent in x
        and y, with a 15% margin, fills the frame (for the bundled head: about 1.3 m).
    """
    v = np.asarray(mesh.vertices, np.float64)
    lo, hi = v.min(0), v.max(0)
    c = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    dist = _MARGIN * max(half[0], half[1]) / np.tan(np.deg2rad(FRONT_FOV_DEG / 2)) + half[2]
    return look_at((c[0], c[1], c[2] + dist), tuple(c), fov_deg=FRONT_FOV_DEG, width=size, height=size)


def front_ring(mesh, n: int, size: int) -> tuple[Camera, ...]:
    """``n`` front cameras over 80 degrees of azimuth around a mesh.

    Args:
        mesh: anything with ``vertices`` [N, 3] in mm.
        n: the number of cameras (at least 1).
        size: each image's width and height in pixels.

    Returns:
        n = 1: ``(front_camera(mesh, size),)``; n > 1: ``stage.camera_ring`` of n cameras at the front
        camera's distance from the vertical axis through the mesh's centre, at its height, from -40 to +40
        degrees of azimuth, aimed at the centre (the demo's and the photo round trip's several views).
    """
    front = front_camera(mesh, size)
    if n == 1:
        return (front,)
    v = np.asarray(mesh.vertices, np.float64)
    c = 0.5 * (v.min(0) + v.max(0))
    eye = -np.asarray(front.R, np.float64).T @ np.asarray(front.t, np.float64)
    return camera_ring(n, float(np.hypot(eye[0], eye[2])), elevation_mm=float(c[1]), target=tuple(c),
                       fov_deg=FRONT_FOV_DEG, width=size, height=size, start_deg=-40.0, arc_deg=80.0)
