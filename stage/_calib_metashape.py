"""Agisoft Metashape's camera export (File > Export > Export Cameras, "Agisoft XML") as cameras.

The file::

    <document version="...">
      <chunk>
        <sensors>
          <sensor id="0" label="..." type="frame">
            <resolution width="W" height="H"/>
            <calibration type="frame" class="adjusted">
              <resolution width="W" height="H"/> <f/> <cx/> <cy/> <b1/> <b2/> <k1/> <k2/> <k3/> <p1/> <p2/>
            </calibration>
          </sensor>
        </sensors>
        <components> <component id="0"> <transform>...</transform> </component> </components>
        <cameras> <camera id="0" label="..." sensor_id="0" component_id="0"> <transform>16 numbers</transform>
        </camera> </cameras>
        <transform> <rotation>9</rotation> <translation>3</translation> <scale>1</scale> </transform>
      </chunk>
    </document>

Metashape's frame camera (user manual, Appendix C "Camera models"): with (X, Y, Z) in the camera's frame
(x right, y down, z the viewing direction), x = X / Z, y = Y / Z, r^2 = x^2 + y^2,

    x' = x (1 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8) + P1 (r^2 + 2 x^2) + 2 P2 x y
    y' = y (1 + K1 r^2 + K2 r^4 + K3 r^6 + K4 r^8) + P2 (r^2 + 2 y^2) + 2 P1 x y
    u = w / 2 + cx + x' f + x' B1 + y' B2,    v = h / 2 + cy + y' f

(P3, P4 multiply the tangential terms by 1 + P3 r^2 + P4 r^4). So a Camera holds it exactly:
K = [[f + B1, B2, w/2 + cx], [0, f, h/2 + cy], [0, 0, 1]] (B1 the affinity, fx - fy; B2 the skew, as Agisoft's
support states them), and OpenCV's (k1, k2, p1, p2, k3) = (K1, K2, P2, P1, K3): Metashape's P1 goes with
r^2 + 2 x^2 in x', which is OpenCV's p2. K4, P3 and P4 have no place in OpenCV's five and must be 0.
cx and cy are offsets from the image centre, in pixels. Metashape's image coordinates put the top-left pixel's
centre at (0.5, 0.5) (u = w / 2 is the image centre), the Camera's convention: no half-pixel shift.

A camera's ``transform`` is camera to chunk (4x4, row-major); the chunk's ``transform`` (rotation R,
translation T, scale s; or, from Metashape 1.6, its component's) maps chunk coordinates p to world ones,
s R p + T: metres for a chunk scaled by scale bars or referenced to a local or projected coordinate system,
geocentric metres for a geographic one (then far beyond ``MAX_COORDINATE_MM`` and refused).

References: Agisoft Metashape User Manual, Professional Edition, Appendix C "Camera models" (frame cameras);
Agisoft's knowledge base, "What do camera calibration results mean in Metashape?".
"""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ._calib_common import CENTRES_AT_HALVES, build_camera, mm_per_unit_value
from ._camera import Camera
from ._files import existing_path

# Calibration terms that OpenCV's five coefficients cannot hold; a file with any of them non-zero is refused.
_UNMAPPED = ("k4", "p3", "p4")
# Older PhotoScan exports wrote fx / fy / skew with an absolute principal point: another model, refused by name.
_OLD_TERMS = ("fx", "fy", "skew")


def _number(elem: ET.Element | None, where: str, field: str, default: float | None = None) -> float:
    """The float in ``elem``'s text (``default`` when the element is absent)."""
    if elem is None:
        if default is None:
            raise ValueError(f"{where}: missing field {field!r}")
        return default
    try:
        value = float((elem.text or "").strip())
    except ValueError:
        raise ValueError(f"{where}: field {field!r} must be a number, got {elem.text!r}") from None
    if not np.isfinite(value):
        raise ValueError(f"{where}: field {field!r} must be finite, got {value}")
    return value


def _numbers(elem: ET.Element | None, where: str, field: str, n: int) -> np.ndarray | None:
    """The ``n`` floats in ``elem``'s text (None when the element is absent)."""
    if elem is None:
        return None
    try:
        values = np.array([float(x) for x in (elem.text or "").split()])
    except ValueError:
        raise ValueError(f"{where}: field {field!r} must be {n} numbers, got {elem.text!r}") from None
    if values.size != n or not np.all(np.isfinite(values)):
        raise ValueError(f"{where}: field {field!r} must be {n} finite numbers, got {values.size}: {elem.text!r}")
    return values


def _size(elem: ET.Element | None, where: str) -> tuple[int, int] | None:
    """A ``<resolution width height/>`` as integers (None when absent)."""
    if elem is None:
        return None
    try:
        return int(elem.get("width", "")), int(elem.get("height", ""))
    except ValueError:
        raise ValueError(f"{where}: field 'resolution' needs integer width and height, got "
                         f"{dict(elem.attrib)}") from None


def _sensor(sensor: ET.Element, path: Path) -> tuple[np.ndarray, np.ndarray, int, int]:
    """K [3, 3] (the Camera's pixel convention), OpenCV's five coefficients and the image size of a frame sensor."""
    where = f"{path}: sensor {sensor.get('id')!r} ({sensor.get('label', '')!r})"
    kind = sensor.get("type", "frame")
    calibs = sensor.findall("calibration")
    calib = next((c for c in calibs if c.get("class") == "adjusted"), calibs[0] if calibs else None)
    if calib is not None:
        kind = calib.get("type", kind)
    if kind != "frame":
        raise ValueError(f"{where}: sensor type {kind!r} is not supported (only 'frame': a pinhole with Brown's "
                         "distortion); undistort the photos in Metashape and export those cameras")
    if calib is None:
        raise ValueError(f"{where}: missing field 'calibration' (the sensor was never calibrated or aligned)")
    for term in _OLD_TERMS:
        if calib.find(term) is not None:
            raise ValueError(f"{where}: field {term!r}: an older PhotoScan calibration (fx, fy, skew, an absolute "
                             "principal point) is not supported; export again from Metashape")
    size = _size(calib.find("resolution"), where) or _size(sensor.find("resolution"), where)
    other = _size(sensor.find("resolution"), where)
    if size is None:
        raise ValueError(f"{where}: missing field 'resolution'")
    if other is not None and other != size:
        raise ValueError(f"{where}: field 'resolution': the sensor's {other} and its calibration's {size} differ")
    for term in _UNMAPPED:
        if _number(calib.find(term), where, term, 0.0) != 0.0:
            raise ValueError(f"{where}: field {term!r} is not zero: OpenCV's k1, k2, p1, p2, k3 cannot hold it "
                             "(fix it at 0 in Metashape's camera calibration and optimise again)")
    f = _number(calib.find("f"), where, "f")
    cx, cy, b1, b2 = (_number(calib.find(k), where, k, 0.0) for k in ("cx", "cy", "b1", "b2"))
    k1, k2, k3, p1, p2 = (_number(calib.find(k), where, k, 0.0) for k in ("k1", "k2", "k3", "p1", "p2"))
    w, h = size
    K = np.array([[f + b1, b2, w / 2 + cx], [0.0, f, h / 2 + cy], [0.0, 0.0, 1.0]])
    return K, np.array([k1, k2, p2, p1, k3]), w, h  # Metashape's P1, P2 are OpenCV's p2, p1


def _similarity(transform: ET.Element | None, where: str) -> tuple[np.ndarray, np.ndarray, float]:
    """A chunk's or component's ``<transform>``: rotation R [3, 3], translation T [3] and scale s (world =
    s R p + T); the identity when absent, and for each absent part."""
    if transform is None:
        return np.eye(3), np.zeros(3), 1.0
    R = _numbers(transform.find("rotation"), where, "rotation", 9)
    T = _numbers(transform.find("translation"), where, "translation", 3)
    s = _number(transform.find("scale"), where, "scale", 1.0)
    if not s > 0:
        raise ValueError(f"{where}: field 'scale' must be positive, got {s}")
    return (np.eye(3) if R is None else R.reshape(3, 3)), (np.zeros(3) if T is None else T), s


def _read_xml(path: Path) -> ET.Element:
    """The document element, parsed; a DOCTYPE (entity definitions, which Metashape never writes) refused."""
    data = path.read_bytes()
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise ValueError(f"{path}: a DOCTYPE or entity definition is not allowed in a Metashape camera file")
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise ValueError(f"{path}: not valid XML ({exc})") from None
    if root.tag != "document":
        raise ValueError(f"{path}: expected a Metashape <document>, got <{root.tag}>")
    return root


def read_metashape_xml(path, mm_per_unit: float | str) -> dict[str, Camera]:
    """The aligned cameras of an Agisoft Metashape camera export (XML).

    Each camera's sensor must be a frame camera (a pinhole with Brown's distortion): K and OpenCV's
    distortion hold Metashape's model exactly (module docstring: cx, cy are offsets from the image centre,
    B1 / B2 the affinity and skew, Metashape's P1 / P2 OpenCV's p2 / p1; K4, P3, P4 must be 0). Metashape's
    pixel convention is the Camera's (the top-left pixel's centre at (0.5, 0.5)): no shift. The pose is the
    inverse of camera to world, where camera to world is the chunk's (or the camera's component's) similarity
    transform after the camera's camera-to-chunk transform; its translation is scaled by ``mm_per_unit``.
    Cameras without a transform (not aligned) are skipped, with one warning naming them all.

    Args:
        path: the exported .xml file.
        mm_per_unit: millimetres per unit of the chunk's world coordinates (1000 for a chunk in metres), a
            positive finite number or "mm", "cm", "m".

    Returns:
        ``{label: Camera}`` for the aligned cameras, in the file's order, keyed by the camera's label (as
        Metashape lists it: by default the photo's file name).

    Raises:
        FileNotFoundError naming the path. ValueError naming the file, the camera or sensor and the field: XML
        that does not parse or is not a Metashape document, several chunks, a sensor that is not a frame
        camera (fisheye, spherical, cylindrical, RPC: named with its id and label) or holds K4 / P3 / P4 or
        an older PhotoScan's fx / fy terms, a camera whose sensor is missing, a label listed twice, no aligned
        camera, and whatever ``stage.camera_from_dict`` refuses.

    Warns:
        UserWarning listing the cameras skipped for having no transform.

    References:
        Agisoft Metashape User Manual, Appendix C "Camera models"; Agisoft's knowledge base.
    """
    mm = mm_per_unit_value(mm_per_unit)
    path = existing_path(path, "Metashape camera file")
    chunks = _read_xml(path).findall("chunk")
    if len(chunks) != 1:
        raise ValueError(f"{path}: expected one <chunk>, got {len(chunks)}; export the cameras of one chunk")
    chunk = chunks[0]
    sensors = {s.get("id"): s for s in chunk.iter("sensor")}
    components = {c.get("id"): c.find("transform") for c in chunk.iter("component")}
    chunk_transform = _similarity(chunk.find("transform"), f"{path}: chunk 'transform'")
    cams = chunk.find("cameras")
    out: dict[str, Camera] = {}
    skipped = []
    for cam in [] if cams is None else cams.iter("camera"):
        label = cam.get("label", cam.get("id", ""))
        where = f"{path}: camera {label!r}"
        M = _numbers(cam.find("transform"), where, "transform", 16)
        if M is None:
            skipped.append(label)
            continue
        if label in out:
            raise ValueError(f"{where} is listed twice")
        M = M.reshape(4, 4)
        if np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-9:
            raise ValueError(f"{where}: field 'transform' must end with the row 0 0 0 1, got {M[3].tolist()}")
        if cam.get("sensor_id") not in sensors:
            raise ValueError(f"{where}: field 'sensor_id': sensor {cam.get('sensor_id')!r} is not in <sensors>")
        K, dist, w, h = _sensor(sensors[cam.get("sensor_id")], path)
        component = components.get(cam.get("component_id"))
        Rk, Tk, s = (chunk_transform if component is None
                     else _similarity(component, f"{path}: component {cam.get('component_id')!r} 'transform'"))
        R = (Rk @ M[:3, :3]).T  # world to camera
        centre = s * Rk @ M[:3, 3] + Tk
        out[label] = build_camera(where, K, R, -R @ centre, w, h, dist, CENTRES_AT_HALVES, mm)
    if skipped:
        warnings.warn(f"{path}: {len(skipped)} camera(s) without a transform (not aligned) skipped: "
                      f"{', '.join(skipped)}", UserWarning, stacklevel=2)
    if not out:
        raise ValueError(f"{path}: no aligned camera (no <camera> with a <transform>)")
    return out
