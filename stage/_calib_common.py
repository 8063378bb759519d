"""What the calibration importers share (``_calib_colmap``, ``_calib_opencv``, ``_calib_metashape``): the
units check, the two rotation parametrisations the formats write (Hamilton quaternions, Rodrigues vectors), the
checks on a file path, and the one way a reader turns what it read into a :class:`~stage.Camera`
(:func:`build_camera`, through ``camera_from_dict``, the camera schema's own validation)."""

from __future__ import annotations

import math

import numpy as np

from ._camera import Camera, camera_from_dict
from ._mesh import LENGTH_UNITS_MM

# The length units a caller may name instead of a number of millimetres per unit.
UNIT_NAMES = LENGTH_UNITS_MM

# The pixel conventions of stage._camera.CONVENTIONS by what they mean: the top-left pixel's centre at (0, 0)
# (OpenCV: cx, cy gain 0.5 in a Camera) or at (0.5, 0.5) (COLMAP, Metashape and the Camera itself: no shift).
CENTRES_AT_INTEGERS = "opencv"
CENTRES_AT_HALVES = "colmap"

# A quaternion or Rodrigues vector this close to zero has no direction: refused rather than divided by.
_TINY = 1e-12


def mm_per_unit_value(mm_per_unit: float | str) -> float:
    """Millimetres per unit of a calibration file's lengths: a positive, finite number, or a unit's name.

    Args:
        mm_per_unit: a number (mm per unit; 1000 for a model in metres) or one of ``UNIT_NAMES``
            ("mm", "cm", "m").

    Returns:
        The number of millimetres per unit, as a float.

    Raises:
        ValueError naming ``mm_per_unit`` when it is zero, negative, not finite, a bool or an unknown name:
        calibrations from structure from motion are in arbitrary units, so the caller must say which.
    """
    if isinstance(mm_per_unit, str):
        if mm_per_unit not in UNIT_NAMES:
            raise ValueError(f"argument 'mm_per_unit': unknown unit {mm_per_unit!r}; give a number of mm per unit "
                             f"or one of {sorted(UNIT_NAMES)}")
        return UNIT_NAMES[mm_per_unit]
    number = not isinstance(mm_per_unit, bool) and isinstance(mm_per_unit, (int, float, np.integer, np.floating))
    if not (number and math.isfinite(float(mm_per_unit)) and float(mm_per_unit) > 0):
        raise ValueError(f"argument 'mm_per_unit' must be a positive, finite number of mm per unit (or one of "
                         f"{sorted(UNIT_NAMES)}), got {mm_per_unit!r}")
    return float(mm_per_unit)


def quaternion_to_matrix(q, where: str) -> np.ndarray:
    """The rotation matrix of a Hamilton quaternion (w, x, y, z) (COLMAP's QW QX QY QZ), normalised first.

    Args:
        q: four numbers, scalar first.
        where: the file and field, for the message.

    Returns:
        R [3, 3] (float64) with R v = q v q^*.

    Raises:
        ValueError starting with ``where`` when q is not four finite numbers or has zero length.

    References:
        Hamilton's convention as COLMAP uses it (``qvec2rotmat`` in COLMAP's scripts/python/read_write_model.py).
    """
    q = np.asarray(q, np.float64).reshape(-1)
    norm = float(np.linalg.norm(q)) if q.size == 4 and np.all(np.isfinite(q)) else 0.0
    if not norm > _TINY:
        raise ValueError(f"{where}: a rotation quaternion must be 4 finite numbers of non-zero length, got "
                         f"{q.tolist()}")
    w, x, y, z = q / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def rodrigues_to_matrix(rvec, where: str) -> np.ndarray:
    """The rotation matrix of a Rodrigues vector (axis times angle in radians), as OpenCV's ``cv2.Rodrigues``.

    Args:
        rvec: three numbers (radians).
        where: the file and field, for the message.

    Returns:
        R [3, 3] (float64) = cos(theta) I + (1 - cos(theta)) k k^T + sin(theta) [k]_x, theta = |rvec|,
        k = rvec / theta (the identity for a zero vector).

    Raises:
        ValueError starting with ``where`` when rvec is not three finite numbers.

    References:
        The OpenCV calib3d documentation, ``Rodrigues``.
    """
    r = np.asarray(rvec, np.float64).reshape(-1)
    if r.size != 3 or not np.all(np.isfinite(r)):
        raise ValueError(f"{where}: a Rodrigues vector must be 3 finite numbers, got {r.tolist()}")
    theta = float(np.linalg.norm(r))
    if theta < _TINY:
        return np.eye(3)
    k = r / theta
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return math.cos(theta) * np.eye(3) + (1 - math.cos(theta)) * np.outer(k, k) + math.sin(theta) * cross


def build_camera(where: str, K, R, t, width, height, dist, convention: str, mm_per_unit: float) -> Camera:
    """A pinhole :class:`~stage.Camera` from a reader's values, checked as a camera file's are.

    Args:
        where: the file and camera, the start of every message (e.g. ``"sparse/0/cameras.txt: camera 3"``).
        K: intrinsics [3, 3] in pixels, in the file's pixel convention.
        R: world-to-camera rotation [3, 3] (x right, y down, z forward).
        t: world-to-camera translation [3] in the file's units.
        width, height: image size in pixels.
        dist: OpenCV's (k1, k2, p1, p2[, k3]), 0, 4 or 5 numbers.
        convention: ``CENTRES_AT_INTEGERS`` ("opencv": the top-left pixel's centre at (0, 0); cx, cy gain 0.5)
            or ``CENTRES_AT_HALVES`` ("colmap": at (0.5, 0.5), the Camera's own; no shift).
        mm_per_unit: millimetres per unit of ``t`` (checked by :func:`mm_per_unit_value`).

    Returns:
        The camera, t in millimetres.

    Raises:
        ValueError starting with ``where`` and naming the field, from ``stage.camera_from_dict``: K upper
        triangular with positive focal lengths, R a rotation, t finite and within ``MAX_COORDINATE_MM``, a
        positive image size within ``MAX_CAMERA_PIXELS``, 4 or 5 distortion coefficients.
    """
    t_mm = np.asarray(t, np.float64) * mm_per_unit_value(mm_per_unit)
    dist = np.asarray(dist, np.float64).reshape(-1)
    doc = {"K": np.asarray(K, np.float64), "R": np.asarray(R, np.float64), "t": t_mm, "width": width,
           "height": height, "distortion": dist if dist.size else None, "model": "pinhole"}
    return camera_from_dict(doc, where, convention)
