"""Rigs as JSON: the one schema shared by rig files (``save_rig`` /
``load_rig``), capture folders (``relight.io.write_capture``'s ``rig.json``),
map sets and the ``relight`` CLI (``--rig rig.json``)::

    {"positions": [[x, y, z], ...],      L rows, mm (distant lights: direction x radius)
     "intensities": [[r, g, b], ...],    L rows (radiant intensity, or irradiance if distant)
     "solid_angles": [...],              L values, sr (optional: else Voronoi cells)
     "near_field": true | false,
     "units": {...}}                     free text, ignored on reading

Reading also takes ``"directions"`` (unit or not, [L, 3]) instead of
``"positions"``: the form of capture folders from other tools (and DiLiGenT-like
rigs); the lights are then placed 1 m out along them. ``near_field`` defaults
to true for ``positions`` alone, false when ``directions`` are given; ``intensities`` defaults
to 1 (scalar, [L] or [L, C] accepted, as ``make_rig``). Extra keys are ignored.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ._atomic import atomic_write_text
from ._files import read_json
from ._mesh import MAX_COORDINATE_MM
from ._rig import Rig, check_light_count, make_rig

__all__ = ["load_rig", "rig_from_dict", "rig_to_dict", "save_rig"]

# Where a rig given by ``directions`` puts its lights: 1 m from the centre (the
# distance only matters for near-field rigs; distant lights use the direction).
_DIRECTION_RADIUS_MM = 1000.0

UNITS = {"positions": "mm (distant lights: direction x radius)",
         "intensities": "radiant intensity (near field) or irradiance at normal incidence (distant)",
         "solid_angles": "sr"}


def rig_to_dict(rig: Rig) -> dict:
    """The rig as a JSON-ready dict (module docstring schema; lists of float64)."""
    return {"positions": np.asarray(rig.position, np.float64).tolist(),
            "intensities": np.asarray(rig.intensity, np.float64).tolist(),
            "solid_angles": np.asarray(rig.solid_angle, np.float64).tolist(),
            "near_field": bool(rig.near_field), "units": dict(UNITS)}


def position_key(doc: Mapping, where: str) -> str:
    """Which field holds the lights: ``"positions"`` or else ``"directions"``;
    ValueError starting with ``where`` when neither is there."""
    key = "positions" if "positions" in doc else "directions" if "directions" in doc else None
    if key is None:
        raise ValueError(f"{where}: rig needs field 'positions' or 'directions' ([L, 3])")
    return key


def position_array(doc: Mapping, key: str, where: str) -> np.ndarray:
    """Field ``key`` of ``doc`` as float64 [L, 3], L >= 1, finite and within
    ``MAX_COORDINATE_MM``; ValueError starting with ``where`` and naming the
    field otherwise."""
    try:
        pos = np.asarray(doc[key], np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{where}: field {key!r} must be [L, 3] numbers ({err})") from None
    if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] == 0:
        raise ValueError(f"{where}: field {key!r} must be [L, 3] with L >= 1, got shape {pos.shape}")
    if not np.all(np.abs(pos) <= MAX_COORDINATE_MM):  # NaN too
        raise ValueError(f"{where}: field {key!r} must be finite numbers within {MAX_COORDINATE_MM:.0e} "
                         "(stage.MAX_COORDINATE_MM)")
    return pos


def rig_from_dict(doc: object, where: str = "rig") -> Rig:
    """A rig from its dict (module docstring schema). Raises ValueError starting
    with ``where`` (a file name, say) and naming the field that is missing or
    malformed: positions not [L, 3] finite numbers (within
    ``stage.MAX_COORDINATE_MM``), intensities negative, non-finite or all zero,
    solid angles negative or non-finite."""
    if not isinstance(doc, Mapping):
        raise ValueError(f"{where}: a rig must be a JSON object, got {type(doc).__name__}")
    key = position_key(doc, where)
    near = doc.get("near_field", "positions" in doc and "directions" not in doc)
    if not isinstance(near, (bool, np.bool_)) and near not in (0, 1):
        raise ValueError(f"{where}: field 'near_field' must be true or false, got {near!r}")
    pos = position_array(doc, key, where)
    check_light_count(len(pos), f"{where}: field '{key}'")
    if key == "directions":
        norm = np.linalg.norm(pos, axis=1, keepdims=True)
        if not np.all(norm > 0):
            raise ValueError(f"{where}: field 'directions' has a zero vector (row {int(np.argmin(norm))})")
        pos = pos / norm * _DIRECTION_RADIUS_MM
    try:
        inten = np.asarray(doc.get("intensities", 1.0), np.float64)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{where}: field 'intensities' must be numbers ({err})") from None
    if np.any(inten < 0) or not np.all(np.isfinite(inten)):
        raise ValueError(f"{where}: bad rig (light intensities must be finite and non-negative: field 'intensities')")
    if not np.any(inten > 0):
        raise ValueError(f"{where}: field 'intensities': every light has intensity 0; a rig needs a lit light")
    try:
        rig = make_rig(pos, inten, near_field=bool(near))
    except (ValueError, TypeError, IndexError) as err:
        raise ValueError(f"{where}: bad rig ({err})") from None
    if "solid_angles" in doc:
        try:
            omega = np.asarray(doc["solid_angles"], np.float64)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{where}: field 'solid_angles' must be [L] numbers ({err})") from None
        # A mismatched table (a rig subset stored with the full rig's cells) is
        # ignored in favour of the Voronoi cells, as earlier readers did.
        if omega.shape == (rig.num_lights,):
            if not np.all(np.isfinite(omega)) or np.any(omega < 0):
                raise ValueError(f"{where}: field 'solid_angles' must be finite and non-negative")
            rig = Rig(rig.position, rig.intensity, jnp.asarray(omega, jnp.float32), rig.near_field)
    return rig


def save_rig(path, rig: Rig) -> Path:
    """Write ``rig`` to a JSON rig file, atomically (``stage._atomic``)."""
    path = Path(path)
    atomic_write_text(path, json.dumps(rig_to_dict(rig), indent=2, allow_nan=False) + "\n")
    return path


def load_rig(path) -> Rig:
    """Read a rig file (``save_rig``'s, or a capture folder's ``rig.json``).
    Raises FileNotFoundError, or ValueError naming the file and the field."""
    path = Path(path)
    return rig_from_dict(read_json(path, "rig file"), str(path))
