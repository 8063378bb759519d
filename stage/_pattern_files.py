"""Lighting-pattern files: the document a light stage controller plays, one
frame per pattern, every light at its weight (docs/pattern_files.md)::

    {"format": "relight-light-patterns",
     "version": 1,
     "num_lights": L, "num_patterns": K,
     "near_field": true,
     "lights": [{"id": 0, "position_mm": [x, y, z]}, ...],   L entries, in the weights' column order
     "weights": [[w_0, ..., w_{L-1}], ...],                  K rows, fraction of full power in [0, 1]
     "quantization": {"bits": 8, "levels": [[...]], "note": ...},   optional (PWM duty-cycle levels)
     "metadata": {"method": "learned" | "gradient" | "olat" | ..., ...},
     "units": {...}}                                          free text, ignored on reading

The lights' positions are those of the rig the patterns were made for, so a
file is refused on a rig whose lights are elsewhere (or number differently).
Written atomically (``stage._atomic``); every reading error names
the file and the field.
"""

from __future__ import annotations

import json
import math
import numbers
from collections.abc import Mapping
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from ._atomic import atomic_write_text
from ._files import read_json
from ._mesh import MAX_COORDINATE_MM
from ._patterns import check_patterns
from ._rig import Rig

__all__ = ["PATTERN_FORMAT", "PATTERN_FORMAT_VERSION", "PATTERN_POSITION_TOLERANCE_MM", "load_patterns",
           "save_patterns"]

PATTERN_FORMAT = "relight-light-patterns"
PATTERN_FORMAT_VERSION = 1
# Two lights within this distance are the same light: far below any stage's
# light spacing (Light Stage X: ~240 mm between neighbours) and above the
# float32 rounding of positions in metres (~0.1 mm at 1.3 m).
PATTERN_POSITION_TOLERANCE_MM = 1.0
# PWM resolutions a controller drives LEDs with.
_BITS = (8, 10, 12, 16)
_UNITS = {"weights": "fraction of the light's full power (PWM duty cycle), the same for every colour channel",
          "position_mm": "mm, stage frame (x right, y up, z toward the main camera); distant lights: direction x "
                         "radius",
          "quantization.levels": "integer duty-cycle level, weight = level / (2^bits - 1)"}


def _jsonable(x, where: str):
    """``x`` as plain JSON types; ValueError naming ``where`` when it is not representable (NaN, objects)."""
    try:
        text = json.dumps(x, allow_nan=False)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{where} must be JSON-serialisable (no NaN / Inf): {err}") from None
    return json.loads(text)


def save_patterns(path, patterns, rig: Rig, *, metadata: Mapping | None = None, light_ids=None,
                  bits: int | None = None) -> Path:
    """Write ``patterns`` [K, L] (weights in [0, 1], ValueError naming
    ``patterns`` otherwise) for ``rig`` as a pattern file
    (docs/pattern_files.md), atomically. ``metadata``: a JSON-serialisable
    dict stored as it is (e.g. {"method": "learned", "training": {...}});
    ``light_ids``: the controller's id of each light (default 0..L-1, the
    rig's order); ``bits`` (8, 10, 12 or 16): also store the weights as
    integer PWM duty-cycle levels round(w (2^bits - 1)), and store the weights
    as those levels / (2^bits - 1), so the file's weights are exactly what
    the LEDs can play."""
    path = Path(path)
    if not isinstance(rig, Rig):
        raise ValueError(f"save_patterns: rig must be a stage.Rig, got {type(rig).__name__}")
    L = rig.num_lights
    check_patterns(patterns, L)  # ValueError naming patterns
    W = np.asarray(patterns, np.float64)  # the caller's values, not check_patterns' float32 copy
    ids = np.arange(L) if light_ids is None else np.asarray(light_ids)
    if ids.shape != (L,) or not np.issubdtype(ids.dtype, np.integer) or len(np.unique(ids)) != L:
        raise ValueError(f"save_patterns: light_ids must be {L} distinct integers, got shape {ids.shape}")
    doc = {"format": PATTERN_FORMAT, "version": PATTERN_FORMAT_VERSION, "num_lights": L,
           "num_patterns": int(W.shape[0]), "near_field": bool(rig.near_field),
           "lights": [{"id": int(i), "position_mm": [float(v) for v in p]}
                      for i, p in zip(ids, np.asarray(rig.position, np.float64), strict=True)]}
    if bits is not None:
        if isinstance(bits, bool) or bits not in _BITS:
            raise ValueError(f"save_patterns: bits must be one of {_BITS} (PWM resolution) or None, got {bits!r}")
        top = (1 << int(bits)) - 1
        levels = np.rint(W * top).astype(np.int64)
        W = levels / top
        doc["quantization"] = {"bits": int(bits), "levels": levels.tolist(),
                               "note": f"weights are duty-cycle levels / {top}: what a {bits}-bit PWM LED driver "
                                       "plays exactly"}
    doc["weights"] = W.tolist()
    doc["metadata"] = {} if metadata is None else _jsonable(dict(metadata), "save_patterns: metadata")
    doc["units"] = dict(_UNITS)
    atomic_write_text(path, json.dumps(doc, allow_nan=False) + "\n")
    return path


def _int_field(doc: Mapping, key: str, where: str) -> int:
    v = doc.get(key)
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise ValueError(f"{where}: field {key!r} must be a positive integer, got {v!r}")
    return v


def _number_rows(rows, K: int, L: int, where: str, field: str, lo: float, hi: float) -> np.ndarray:
    """``rows`` as float64 [K, L]: a list of K lists of L JSON numbers (not bools), finite, in [lo, hi]."""
    if not isinstance(rows, list) or len(rows) != K:
        raise ValueError(f"{where}: field {field!r} must be a list of {K} rows (num_patterns)")
    out = np.empty((K, L), np.float64)
    for k, row in enumerate(rows):
        if not isinstance(row, list) or len(row) != L:
            raise ValueError(f"{where}: field {field!r} row {k} must hold {L} numbers (num_lights)")
        for l_, v in enumerate(row):
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) or not lo <= v <= hi:
                raise ValueError(f"{where}: field {field!r} pattern {k}, light {l_}: {v!r} is not a number in "
                                 f"[{lo:g}, {hi:g}]")
            out[k, l_] = v
    return out


def _lights(doc: Mapping, L: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    lights = doc.get("lights")
    if not isinstance(lights, list) or len(lights) != L:
        raise ValueError(f"{where}: field 'lights' must be a list of {L} lights (num_lights)")
    ids, pos = [], []
    for i, light in enumerate(lights):
        if not isinstance(light, Mapping):
            raise ValueError(f"{where}: field 'lights' entry {i} must be an object with 'id' and 'position_mm'")
        lid = light.get("id")
        if isinstance(lid, bool) or not isinstance(lid, int):
            raise ValueError(f"{where}: field 'lights' entry {i}: 'id' must be an integer, got {lid!r}")
        p = light.get("position_mm")
        if (not isinstance(p, list) or len(p) != 3
                or not all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in p)
                or not all(math.isfinite(v) and abs(v) <= MAX_COORDINATE_MM for v in p)):
            raise ValueError(f"{where}: field 'lights' entry {i}: 'position_mm' must be 3 finite numbers within "
                             f"{MAX_COORDINATE_MM:.0e} mm")
        ids.append(lid)
        pos.append(p)
    ids = np.asarray(ids, np.int64)
    if len(np.unique(ids)) != L:
        raise ValueError(f"{where}: field 'lights' has repeated ids")
    return ids, np.asarray(pos, np.float64)


def _check_rig(rig: Rig, pos: np.ndarray, near: bool, where: str) -> None:
    if not isinstance(rig, Rig):
        raise ValueError(f"load_patterns: rig must be a stage.Rig or None, got {type(rig).__name__}")
    if rig.num_lights != len(pos):
        raise ValueError(f"{where}: the patterns are for a rig of {len(pos)} lights, this rig has {rig.num_lights}")
    if bool(rig.near_field) != near:
        raise ValueError(f"{where}: the patterns are for a {'near-field' if near else 'distant-light'} rig, this "
                         f"rig's lights are {'near-field' if rig.near_field else 'distant'}")
    d = np.linalg.norm(np.asarray(rig.position, np.float64) - pos, axis=1)
    if np.any(d > PATTERN_POSITION_TOLERANCE_MM):
        i = int(np.argmax(d > PATTERN_POSITION_TOLERANCE_MM))
        raise ValueError(f"{where}: made for another rig: light {i} is {d[i]:.1f} mm from the file's position "
                         f"{np.round(pos[i], 1).tolist()} ({int(np.sum(d > PATTERN_POSITION_TOLERANCE_MM))} lights "
                         f"differ by more than {PATTERN_POSITION_TOLERANCE_MM} mm)")


def load_patterns(path, rig: Rig | None = None) -> tuple[jnp.ndarray, dict]:
    """Read a pattern file: (patterns [K, L] float32 in [0, 1], metadata dict).
    With ``rig`` the file must have been made for it: the same number of
    lights, the same near-field flag and every light within
    ``PATTERN_POSITION_TOLERANCE_MM`` (1 mm) of its recorded position, in
    order. The metadata is the file's ``metadata`` object with ``light_ids``
    (the controller's ids, [L]) and, for a quantised file, ``bits`` added.
    Raises FileNotFoundError, or ValueError naming the file and the field
    (wrong format or a newer version, shapes, weights outside [0, 1], NaN)."""
    path = Path(path)
    where = str(path)
    doc = read_json(path, "pattern file")
    if not isinstance(doc, Mapping):
        raise ValueError(f"{where}: a pattern file must be a JSON object, got {type(doc).__name__}")
    if doc.get("format") != PATTERN_FORMAT:
        raise ValueError(f"{where}: field 'format' must be {PATTERN_FORMAT!r} (not a pattern file?), got "
                         f"{doc.get('format')!r}")
    version = doc.get("version")
    if isinstance(version, bool) or not isinstance(version, int) or version < 1:
        raise ValueError(f"{where}: field 'version' must be a positive integer, got {version!r}")
    if version > PATTERN_FORMAT_VERSION:
        raise ValueError(f"{where}: format version {version} is newer than this reader ({PATTERN_FORMAT_VERSION})")
    L = _int_field(doc, "num_lights", where)
    K = _int_field(doc, "num_patterns", where)
    near = doc.get("near_field", True)
    if not isinstance(near, bool):
        raise ValueError(f"{where}: field 'near_field' must be true or false, got {near!r}")
    ids, pos = _lights(doc, L, where)
    W = _number_rows(doc.get("weights"), K, L, where, "weights", 0.0, 1.0)
    meta = doc.get("metadata", {})
    if not isinstance(meta, Mapping):
        raise ValueError(f"{where}: field 'metadata' must be an object, got {type(meta).__name__}")
    meta = dict(meta)
    q = doc.get("quantization")
    if q is not None:
        if not isinstance(q, Mapping) or q.get("bits") not in _BITS or isinstance(q.get("bits"), bool):
            raise ValueError(f"{where}: field 'quantization' must hold 'bits' in {_BITS}")
        top = (1 << q["bits"]) - 1
        if "levels" in q:
            levels = _number_rows(q["levels"], K, L, where, "quantization.levels", 0, top)
            if np.any(levels != np.rint(levels)) or np.any(np.abs(levels / top - W) > 0.5 / top):
                raise ValueError(f"{where}: field 'quantization.levels' must be integers that match 'weights' "
                                 f"(weight = level / {top})")
        meta["bits"] = int(q["bits"])
    meta["light_ids"] = ids.tolist()
    if rig is not None:
        _check_rig(rig, pos, near, where)
    return jnp.asarray(W, jnp.float32), meta
