"""Rigs from the files real light stages ship: ``load_rig_file(path, units, up)``.

Three kinds of file are read:

* ``.json``, the stage rig schema (``stage.rig_to_dict``, see ``_rig_io``)
  extended with three optional fields::

      "units": "mm" | "cm" | "m" | "directions"   what the position rows are in
                                                   ("directions": distant lights;
                                                   a free-text dict, as
                                                   rig_to_dict writes, means mm)
      "calibration": [r, g, b] | [[r, g, b], ...]  per-light RGB gain (stage.calibrate)
      "subsets": {"name": [i, ...], ...}           named light orderings, 0-based

  or a list of per-light records, as stages ship them: a bare JSON list, or
  ``{"lights": [...], "units": ..., "up": ..., "near_field": ..., "subsets": ...}``,
  each record ``{"position": [x, y, z]}`` (or ``"direction"``, the same key in
  every record) with optional ``"intensity"`` (a number or RGB), ``"calibration"``
  (or ``"gain"``: a number or RGB); other fields (``"name"``, ``"id"``, ...)
  are ignored: light i is the i-th record. A record file records neither units nor up axis by
  itself: both must be stated (in the object, or by the caller) for positions,
  ``up`` for directions, else a ValueError saying so.

  or the ICT Light Stage X table (``positions_cm``, ``order_polarized``,
  ``order_unpolarized``: 1-based), e.g. ``../shared/data/lightstage/
  light_stage_x.json``: centimetres, y up, its orderings as the subsets
  ``polarized`` / ``unpolarized``, and its duplicated row 322 restored as
  ``stage.light_stage_x`` does.
* ``.npy`` ([L, 3] float) and ``.txt`` (rows "x y z") position tables, e.g.
  OpenIllumination's ``light_pos.npy``: unit-free and with no recorded up
  axis, so ``units`` and ``up`` must be stated (else a ValueError saying so,
  with a hint where the data suggest an answer).

``up`` ("+x", "-x", "+y", "-y", "+z", "-z"; "x" is "+x") names the file's axis that points
up; the positions are turned by the smallest rotation taking it to the stage's
+y (a 180-degree turn about +x for "-y"). When a file gives no intensities,
every light delivers irradiance 1 at the centre (near field: the intensity
mean(r^2), as ``stage.light_stage_x``; distant: irradiance 1), so photographs
taken under the rig are radiance per unit irradiance, times the calibration.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ._files import read_json, read_light_table
from ._mesh import LENGTH_UNITS_MM, MAX_COORDINATE_MM
from ._rig import _LSX_DUPLICATE_ROW, _LSX_DUPLICATED_ROW, _LSX_ORIGINAL_VALUE_CM, Rig, calibrate, check_light_count
from ._rig_io import position_array, position_key, rig_from_dict

__all__ = ["AXES", "POSITION_UNITS", "load_rig_file", "rig_file_subsets", "up_rotation"]

POSITION_UNITS = {**LENGTH_UNITS_MM, "directions": None}
AXES = {"+x": (1, 0, 0), "-x": (-1, 0, 0), "+y": (0, 1, 0), "-y": (0, -1, 0), "+z": (0, 0, 1), "-z": (0, 0, -1)}
_AXIS_ALIASES = {"x": "+x", "y": "+y", "z": "+z"}
# A gap in the lights this many times wider than their typical spacing is
# taken as the floor (or the camera port) when hinting at the up axis.
_GAP_HINT_RATIO = 1.5


def up_rotation(up: str, where: str = "up") -> np.ndarray:
    """The smallest rotation (Rodrigues) taking the axis ``up`` to +y; a 180-degree turn about +x for "-y".

    Args:
        up: the axis, "+x" ... "-z".
        where: the argument's name in error messages.

    Returns:
        The rotation [3, 3].
    """
    up = _AXIS_ALIASES.get(up, up) if isinstance(up, str) else up
    if not isinstance(up, str) or up not in AXES:
        raise ValueError(f"{where}: up axis must be one of {', '.join(AXES)}, got {up!r}")
    u = np.asarray(AXES[up], np.float64)
    y = np.array([0.0, 1.0, 0.0])
    if u @ y < -0.5:
        return np.diag([1.0, -1.0, -1.0])
    v, c = np.cross(u, y), float(u @ y)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def _up_hint(pos: np.ndarray) -> str:
    """Where the widest empty cap of the light directions is, as a hint."""
    from brdf import fibonacci_sphere

    u = pos / np.linalg.norm(pos, axis=1, keepdims=True)
    probe = np.asarray(fibonacci_sphere(4096, axis=1), np.float64)
    gap = np.arccos(np.clip((probe @ u.T).max(1), -1, 1))
    k = int(np.argmax(gap))
    spacing = np.median(np.arccos(np.clip(np.sort(u @ u.T, axis=1)[:, -2], -1, 1)))
    if len(u) < 4 or gap[k] < _GAP_HINT_RATIO * spacing:
        return "the lights cover the sphere evenly, so the data do not suggest one"
    d = probe[k]
    axis = int(np.argmax(np.abs(d)))
    name = "xyz"[axis]
    sign = "+" if d[axis] > 0 else "-"
    opposite = "-" if sign == "+" else "+"
    return (f"the widest gap between the lights (a {np.degrees(gap[k]):.0f} deg cap, usually the floor) is "
            f"toward {sign}{name}, which suggests up = {opposite}{name}")


def _table(path: Path) -> np.ndarray:
    if path.suffix.lower() == ".npy":
        try:
            # Memory-mapped first: numpy checks the declared shape against the file's size, so a corrupt
            # header declaring 10^12 rows is refused instead of allocated (np.load would allocate it).
            mapped = np.load(path, mmap_mode="r", allow_pickle=False)
            if mapped.ndim >= 1:
                check_light_count(mapped.shape[0], f"{path}")  # before a row is read
            arr = np.array(mapped)
        except MemoryError:
            raise
        except ValueError as err:
            if "stage.MAX_LIGHTS" in str(err):
                raise
            raise ValueError(f"{path}: not a readable .npy array ({type(err).__name__}: {err})") from None
        except Exception as err:  # OSError, EOFError, SyntaxError (the header is a Python literal)
            raise ValueError(f"{path}: not a readable .npy array ({type(err).__name__}: {err})") from None
    else:
        arr = read_light_table(path, "light positions")
    arr = np.asarray(arr)
    check_light_count(len(arr), f"{path}")
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] == 0 or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{path}: light positions must be a numeric [L, 3] array, got shape {arr.shape}")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{path}: light positions contain NaN or Inf")
    if np.abs(arr).max() > MAX_COORDINATE_MM:
        raise ValueError(f"{path}: light positions reach {np.abs(arr).max():.3g}, beyond {MAX_COORDINATE_MM:.0e} "
                         "in any unit (stage.MAX_COORDINATE_MM)")
    return arr


def _subsets(doc: Mapping, n: int, where: str, base: int = 0) -> dict[str, np.ndarray]:
    out = {}
    raw = doc.get("subsets", {})
    if not isinstance(raw, Mapping):
        raise ValueError(f"{where}: field 'subsets' must be an object of name -> [light index, ...]")
    items = {str(k): (v, base) for k, v in raw.items()}
    for name in ("polarized", "unpolarized"):  # the Light Stage X table's orderings (1-based)
        if f"order_{name}" in doc:
            items[name] = (doc[f"order_{name}"], 1)
    for name, (idx, b) in items.items():
        try:
            arr = np.asarray(idx)
        except (TypeError, ValueError):
            arr = np.asarray([])
        if arr.ndim != 1 or arr.size == 0 or not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"{where}: subset {name!r} must be a non-empty list of integer light indices")
        arr = arr.astype(np.int64) - b
        if arr.min() < 0 or arr.max() >= n or len(np.unique(arr)) != len(arr):
            raise ValueError(f"{where}: subset {name!r} must hold distinct light indices in [{b}, {n - 1 + b}]")
        out[str(name)] = arr
    return out


def _declared_units(doc: Mapping, where: str) -> str | None:
    u = doc.get("units")
    if isinstance(u, str):
        if u not in POSITION_UNITS:
            raise ValueError(f"{where}: field 'units' must be one of {', '.join(POSITION_UNITS)}, got {u!r}")
        return u
    if isinstance(u, Mapping) and isinstance(u.get("positions"), str) and u["positions"] in POSITION_UNITS:
        return u["positions"]
    return None  # absent, or rig_to_dict's free-text dict: the stage schema's millimetres


def _default_intensity(pos_mm: np.ndarray, near: bool) -> float:
    return float(np.mean(np.sum(pos_mm**2, axis=1))) if near else 1.0


def _from_positions(pos: np.ndarray, units: str, where: str, doc: Mapping | None = None) -> Rig:
    doc = {} if doc is None else doc
    if units == "directions":
        body = {"directions": pos.tolist(), "near_field": False}
    else:
        pos_mm = pos * POSITION_UNITS[units]
        near = doc.get("near_field", True)
        if not (isinstance(near, bool) or (isinstance(near, int) and near in (0, 1))):
            raise ValueError(f"{where}: field 'near_field' must be true or false, got {near!r}")
        body = {"positions": pos_mm.tolist(), "near_field": bool(near)}
    if "intensities" in doc:
        body["intensities"] = doc["intensities"]
    elif units == "directions" or not body["near_field"]:
        body["intensities"] = 1.0
    else:
        body["intensities"] = _default_intensity(np.asarray(body["positions"]), True)
    if "solid_angles" in doc:
        body["solid_angles"] = doc["solid_angles"]
    rig = rig_from_dict(body, where)
    if "calibration" in doc:
        try:
            rig = calibrate(rig, np.asarray(doc["calibration"], np.float64))
        except (TypeError, ValueError) as err:
            raise ValueError(f"{where}: field 'calibration' ({err})") from None
    return rig


_RECORD_GAINS = ("calibration", "gain")


def _records(doc, where: str, units: str | None, up: str | None) -> dict:
    """A per-light record file (module docstring) as the stage schema's dict: ``positions`` or
    ``directions``, ``intensities`` and ``calibration`` [L, 3] when any record gives them, and the object's
    ``units``, ``up``, ``near_field`` and ``subsets``; ValueError naming the record and field otherwise."""
    meta = {} if isinstance(doc, list) else {k: v for k, v in doc.items() if k != "lights"}
    lights = doc if isinstance(doc, list) else doc["lights"]
    if not isinstance(lights, list) or not lights:
        raise ValueError(f"{where}: field 'lights' must be a non-empty list of light records")
    check_light_count(len(lights), f"{where}: field 'lights'")
    for i, rec in enumerate(lights):
        if not isinstance(rec, Mapping):
            raise ValueError(f"{where}: light {i} must be an object with 'position' or 'direction', got "
                             f"{type(rec).__name__}")
    key = "position" if "position" in lights[0] else "direction" if "direction" in lights[0] else None
    missing = [i for i, rec in enumerate(lights) if key is None or key not in rec]
    if missing:
        raise ValueError(f"{where}: light {missing[0]} has no field {key or 'position'!r} (every record needs "
                         "'position' [x, y, z], or every one 'direction')")
    out = {**meta, f"{key}s": [rec[key] for rec in lights]}
    if key == "position" and units is None and "units" not in meta:
        raise ValueError(f"{where}: light records carry no unit; state it: \"units\": \"mm\" | \"cm\" | \"m\" "
                         "beside \"lights\" (or units= / relight CLI: --rig-units)")
    if up is None and "up" not in meta:
        raise ValueError(f"{where}: light records do not say which axis is up; state it: \"up\": \"+y\" ... "
                         "beside \"lights\" (or up= / relight CLI: --rig-up)")

    def rgb(i: int, name: str, value) -> list[float]:
        try:
            v = np.broadcast_to(np.asarray(value, np.float64), (3,))
        except (TypeError, ValueError):
            raise ValueError(f"{where}: light {i}: field {name!r} must be a number or [r, g, b], got "
                             f"{value!r}") from None
        return v.tolist()

    if any("intensity" in rec for rec in lights):
        out["intensities"] = [rgb(i, "intensity", rec.get("intensity", 1.0)) for i, rec in enumerate(lights)]
    gains = [next((rec[g] for g in _RECORD_GAINS if g in rec), None) for rec in lights]
    if any(g is not None for g in gains):
        out["calibration"] = [rgb(i, "calibration", 1.0 if g is None else g) for i, g in enumerate(gains)]
    return out


def _read(path: Path, units: str | None, up: str | None) -> tuple[Rig, dict[str, np.ndarray]]:
    where = str(path)
    if units is not None and (not isinstance(units, str) or units not in POSITION_UNITS):
        raise ValueError(f"{where}: units must be one of {', '.join(POSITION_UNITS)}, got {units!r}")
    suffix = path.suffix.lower()
    if suffix == ".json":
        doc = read_json(path, "rig file")
        if isinstance(doc, list) or (isinstance(doc, Mapping) and "lights" in doc):
            doc = _records(doc, where, units, up)
        if not isinstance(doc, Mapping):
            raise ValueError(f"{where}: a rig file must be a JSON object or a list of light records, got "
                             f"{type(doc).__name__}")
        if "positions_cm" in doc:  # the ICT Light Stage X table
            try:
                pos = np.asarray(doc["positions_cm"], np.float64)
            except (TypeError, ValueError) as err:
                raise ValueError(f"{where}: field 'positions_cm' must be [L, 3] numbers ({err})") from None
            if pos.ndim != 2 or pos.shape[1] != 3:
                raise ValueError(f"{where}: field 'positions_cm' must be [L, 3], got shape {pos.shape}")
            if (len(pos) > _LSX_DUPLICATE_ROW
                    and np.allclose(pos[_LSX_DUPLICATE_ROW], pos[_LSX_DUPLICATED_ROW])):
                pos[_LSX_DUPLICATE_ROW] = _LSX_ORIGINAL_VALUE_CM  # see stage.light_stage_x
            units_, up_ = units or "cm", up or "+y"
            rest = {k: v for k, v in doc.items() if k in ("intensities", "calibration")}
        else:
            key = position_key(doc, where)
            pos = position_array(doc, key, where)
            declared = "directions" if key == "directions" else _declared_units(doc, where)
            units_ = units or declared or "mm"
            up_ = up or doc.get("up", "+y")
            rest = doc
        subsets = _subsets(doc, len(pos), where)
    elif suffix in (".npy", ".txt"):
        pos = _table(path)
        r = np.linalg.norm(pos, axis=1)
        if units is None:
            raise ValueError(f"{where}: light positions carry no unit (radius {r.min():.3g}-{r.max():.3g}); "
                             f"state it: units 'mm' | 'cm' | 'm' | 'directions' (distant lights) "
                             f"(relight CLI: --rig-units)")
        if up is None:
            raise ValueError(f"{where}: the file does not record which axis is up; state it: up "
                             f"'+x' | '-x' | '+y' | '-y' | '+z' | '-z' (relight CLI: --rig-up); {_up_hint(pos)}")
        units_, up_, rest, subsets = units, up, {}, {}
    else:
        raise ValueError(f"{where}: unknown rig file type {path.suffix!r}; expected .json, .npy or .txt")
    if not isinstance(up_, str):
        raise ValueError(f"{where}: field 'up' must be one of {', '.join(AXES)}, got {up_!r}")
    pos = pos @ up_rotation(up_, f"{where}: field 'up'").T
    return _from_positions(pos, units_, where, rest), subsets


def load_rig_file(path, units: str | None = None, up: str | None = None, subset: str | None = None) -> Rig:
    """A ``stage.Rig`` from a rig file of any kind in the module docstring.

    Args:
        path: the rig file.
        units: the position units; states (and overrides) what the file declares. A ``.npy`` or ``.txt`` table
            needs it.
        up: the file's up axis ("+x" ... "-z"); as ``units``.
        subset: a named light ordering (``rig_file_subsets``), e.g. ``"polarized"`` on the Light Stage X table.

    Returns:
        The ``Rig``.

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming the file and the field.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing (rig file)")
    rig, subsets = _read(path, units, up)
    if subset is None:
        return rig
    if not isinstance(subset, str) or subset not in subsets:
        raise ValueError(f"{path}: no light subset {subset!r}; the file has {sorted(subsets) or 'none'}")
    return rig.subset(subsets[subset])


def rig_file_subsets(path) -> dict[str, np.ndarray]:
    """The named light subsets of a rig file.

    Args:
        path: the rig file.

    Returns:
        ``name -> 0-based indices`` into its lights.
    """
    path = Path(path)
    if path.suffix.lower() != ".json":
        return {}
    doc = read_json(path, "rig file")
    if isinstance(doc, list) or (isinstance(doc, Mapping) and "lights" in doc):
        doc = _records(doc, str(path), "mm", "+y")  # only the subsets are read: units and up do not matter
    if not isinstance(doc, Mapping):
        return {}
    if "positions_cm" in doc:
        rows = doc["positions_cm"]
        n = len(rows) if isinstance(rows, list) else 0
    else:
        n = len(position_array(doc, position_key(doc, str(path)), str(path)))
    return _subsets(doc, n, str(path))
