"""OpenCV calibration files as cameras: OpenCV's FileStorage YAML (``cv::FileStorage``, ``%YAML:1.0`` with
``!!opencv-matrix`` nodes) or JSON with the same keys, for one camera or several.

The keys (the first spelling is OpenCV's calibration sample's; each field may be spelt one way only per camera):

| field | spellings | value |
| --- | --- | --- |
| intrinsics | camera_matrix, K, cameraMatrix | 3x3, pixels |
| distortion | distortion_coefficients, dist, D, distCoeffs | 4 or 5: k1, k2, p1, p2[, k3] (optional) |
| rotation | R (3x3) or rvec (3, Rodrigues, radians) | world to camera |
| translation | T, t, tvec | 3, world to camera, the file's units |
| image size | image_width / image_height, width / height | pixels |

OpenCV's pixel convention puts the top-left pixel's centre at (0, 0): cx and cy gain 0.5 in the Camera.
OpenCV's camera axes are the Camera's (x right, y down, z forward). The rational and thin-prism distortion
models (8, 12 or 14 coefficients) are refused.

The YAML is read by a parser of the subset FileStorage writes (block mappings and sequences by indentation,
flow sequences ``[...]`` over several lines, ``!!opencv-matrix`` / ``!!opencv-nd-matrix`` nodes, numbers and
strings), so PyYAML is not needed. FileStorage's XML form is refused (write YAML or JSON).

References: the OpenCV documentation, "File Input and Output using XML / YAML / JSON files" and calib3d's
"Camera Calibration and 3D Reconstruction" (``projectPoints``, ``Rodrigues``).
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ._calib_common import CENTRES_AT_INTEGERS, build_camera, mm_per_unit_value, rodrigues_to_matrix
from ._camera import Camera
from ._files import existing_path, read_json

_SPELLINGS = {
    "K": ("camera_matrix", "K", "cameraMatrix"),
    "dist": ("distortion_coefficients", "dist", "D", "distCoeffs"),
    "R": ("R",),
    "rvec": ("rvec",),
    "t": ("T", "t", "tvec"),
    "width": ("image_width", "width"),
    "height": ("image_height", "height"),
}
_SHAPES = {"K": (3, 3), "R": (3, 3), "rvec": (3,), "t": (3,)}

# ---------------------------------------------------------------------------------------------- the YAML subset

_KEY = re.compile(r"""^("[^"]*"|'[^']*'|[^\s"'\[\]{}#:-][^:#]*?|-[^\s:#][^:#]*?)\s*:(?:\s+|$)(.*)$""")
_SPECIAL = {".nan": float("nan"), ".inf": float("inf"), "+.inf": float("inf"), "-.inf": float("-inf")}


def _scalar(text: str):
    """A plain or quoted YAML scalar: int, float (OpenCV's .Nan / .Inf included) or string."""
    text = text.strip()
    if len(text) >= 2 and text[0] == text[-1] and text[0] in "\"'":
        return text[1:-1]
    if text.lower() in _SPECIAL:
        return _SPECIAL[text.lower()]
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _flow(text: str, at: int, where: str):
    """A flow sequence ``[a, b, [c]]`` starting at ``text[at]`` == '['; returns (list, index after ']')."""
    out, at, n = [], at + 1, len(text)
    while True:
        while at < n and text[at] == " ":
            at += 1
        if at >= n:
            raise ValueError(f"{where}: unterminated flow sequence '['")
        ch = text[at]
        if ch == "]":
            return out, at + 1
        if ch == "[":
            value, at = _flow(text, at, where)
        elif ch == "{":
            raise ValueError(f"{where}: flow mappings ({{...}}) are not supported; write a block mapping")
        elif ch in "\"'":
            end = text.find(ch, at + 1)
            if end < 0:
                raise ValueError(f"{where}: unterminated quoted string")
            value, at = text[at + 1:end], end + 1
        else:
            stops = [k for k in (text.find(",", at), text.find("]", at)) if k >= 0]
            stop = min(stops) if stops else n
            token = text[at:stop].strip()
            if not token:
                raise ValueError(f"{where}: empty item in a flow sequence")
            value, at = _scalar(token), stop
        out.append(value)
        while at < n and text[at] == " ":
            at += 1
        if at < n and text[at] == ",":
            at += 1
        elif at < n and text[at] != "]":
            raise ValueError(f"{where}: malformed flow sequence near {text[at:at + 20]!r}")


def _value(text: str, where: str):
    """The value written after ``key:`` or ``- `` on one (joined) line."""
    if text.startswith("["):
        value, end = _flow(text, 0, where)
        if text[end:].strip():
            raise ValueError(f"{where}: unexpected text after ']': {text[end:].strip()!r}")
        return value
    if text.startswith("{"):
        raise ValueError(f"{where}: flow mappings ({{...}}) are not supported; write a block mapping")
    return _scalar(text)


def _without_comment(line: str) -> str:
    """``line`` up to a ``#`` that starts a comment (at the start, or after a space, outside quotes)."""
    quote = None
    for k, ch in enumerate(line):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch == "#" and (k == 0 or line[k - 1] in " \t"):
            return line[:k]
    return line


def _entries(text: str, path: Path) -> list[tuple[int, int, str, bool]]:
    """The document as (line number, indent, content, is a sequence item) entries: comments, the %YAML
    directive and document markers dropped, flow sequences joined across lines, and a ``- key: value`` item
    split into a bare item and its first key one level deeper."""
    lines = text.splitlines()
    out, i = [], 0
    while i < len(lines):
        raw, lineno = _without_comment(lines[i]).rstrip(), i + 1
        i += 1
        content = raw.strip()
        if not content or content.startswith(("#", "%")) or content in ("---", "..."):
            continue
        indent = len(raw) - len(raw.lstrip(" "))
        if raw[:indent + 1].strip(" ") == "\t":
            raise ValueError(f"{path}:{lineno}: tab in the indentation (YAML indents with spaces)")
        while content.count("[") > content.count("]") and i < len(lines):
            content, i = content + " " + _without_comment(lines[i]).strip(), i + 1
        if content == "-" or content.startswith("- "):
            rest = content[1:].lstrip()
            if rest and _KEY.match(rest):
                out.append((lineno, indent, "", True))
                out.append((lineno, indent + len(content) - len(rest), rest, False))
            else:
                out.append((lineno, indent, rest, True))
        else:
            out.append((lineno, indent, content, False))
    return out


class _Yaml:
    """A recursive-descent reader of the block structure over :func:`_entries`."""

    def __init__(self, text: str, path: Path):
        self.path, self.items, self.at = path, _entries(text, path), 0

    def where(self, k: int | None = None) -> str:
        k = self.at if k is None else k
        return f"{self.path}:{self.items[min(k, len(self.items) - 1)][0]}"

    def document(self):
        if not self.items:
            raise ValueError(f"{self.path}: empty calibration file")
        value = self.node(self.items[0][1])
        if self.at < len(self.items):
            raise ValueError(f"{self.where()}: unexpected indentation")
        return value

    def node(self, indent: int):
        return self.sequence(indent) if self.items[self.at][3] else self.mapping(indent)

    def child(self, indent: int, seq_same_level: bool):
        """The block value under a key or item at ``indent`` (None when there is none)."""
        if self.at >= len(self.items):
            return None
        _, nxt, _, is_item = self.items[self.at]
        if nxt > indent or (seq_same_level and is_item and nxt == indent):
            return self.node(nxt)
        return None

    def mapping(self, indent: int) -> dict:
        out = {}
        while self.at < len(self.items):
            _, ind, content, is_item = self.items[self.at]
            if ind < indent or is_item:
                break
            if ind > indent:
                raise ValueError(f"{self.where()}: unexpected indentation")
            m = _KEY.match(content)
            if m is None:
                raise ValueError(f"{self.where()}: expected 'key: value', got {content!r}")
            key, rest, k = _scalar(m.group(1)), m.group(2).strip(), self.at
            if key in out:
                raise ValueError(f"{self.where()}: key {key!r} appears twice")
            self.at += 1
            if rest.startswith("!!"):
                tag, _, rest = rest.partition(" ")
                body = _value(rest.strip(), self.where(k)) if rest.strip() else self.child(indent, False)
                out[key] = _tagged(tag, body, f"{self.where(k)}: {key!r}")
            elif rest:
                out[key] = _value(rest, self.where(k))
            else:
                out[key] = self.child(indent, True)
        return out

    def sequence(self, indent: int) -> list:
        out = []
        while self.at < len(self.items):
            _, ind, content, is_item = self.items[self.at]
            if ind != indent or not is_item:
                if ind > indent:
                    raise ValueError(f"{self.where()}: unexpected indentation")
                break
            k = self.at
            self.at += 1
            out.append(_value(content, self.where(k)) if content else self.child(indent, False))
        return out


def _tagged(tag: str, body, where: str) -> np.ndarray:
    """An ``!!opencv-matrix`` (rows, cols, dt, data) or ``!!opencv-nd-matrix`` (sizes, dt, data) as float64."""
    if tag not in ("!!opencv-matrix", "!!opencv-nd-matrix"):
        raise ValueError(f"{where}: unsupported tag {tag}")
    if not isinstance(body, Mapping):
        raise ValueError(f"{where}: {tag} must be a mapping with rows, cols, dt and data")
    try:
        shape = (body["rows"], body["cols"]) if tag == "!!opencv-matrix" else tuple(body["sizes"])
        data = np.asarray(body["data"], np.float64).reshape(-1)
    except KeyError as exc:
        raise ValueError(f"{where}: {tag} is missing field {exc.args[0]!r}") from None
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {tag} field 'data' must be a list of numbers ({exc})") from None
    if not all(isinstance(n, int) and n >= 0 for n in shape) or int(np.prod(shape)) != data.size:
        raise ValueError(f"{where}: {tag} declares shape {shape} but holds {data.size} numbers")
    return data.reshape(shape)


def parse_filestorage_yaml(text: str, path) -> object:
    """The document of an OpenCV FileStorage YAML file (the subset FileStorage writes; module docstring).

    Args:
        text: the file's contents.
        path: the file, for the messages.

    Returns:
        dicts, lists, ints, floats and strings; each ``!!opencv-matrix`` as a float64 array [rows, cols].

    Raises:
        ValueError naming the file and line for what the subset does not hold (flow mappings, other tags,
        tabs, bad indentation, a key twice, a matrix whose data does not fill its shape).
    """
    return _Yaml(text, Path(path)).document()


# --------------------------------------------------------------------------------------------------- the cameras


def _field(doc: Mapping, field: str, where: str):
    """The value of ``field`` under its one spelling in ``doc`` (None when absent), as an array of the field's
    shape (a flat 9-list is taken for a 3x3)."""
    present = [k for k in _SPELLINGS[field] if k in doc]
    if len(present) > 1:
        raise ValueError(f"{where}: fields {present} are the same field; give one")
    if not present:
        return None
    key, value = present[0], doc[present[0]]
    if field in ("width", "height"):
        return value
    if isinstance(value, Mapping) and value.get("type_id") in ("opencv-matrix", "opencv-nd-matrix"):
        value = _tagged(f"!!{value['type_id']}", value, f"{where}: field {key!r}")  # FileStorage's JSON form
    try:
        a = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: field {key!r} must be numbers, got {value!r}") from None
    shape = _SHAPES.get(field)
    if shape is not None:
        if a.size != int(np.prod(shape)):
            raise ValueError(f"{where}: field {key!r} must hold {int(np.prod(shape))} numbers (shape {shape}), got "
                             f"shape {a.shape}")
        a = a.reshape(shape)
    return a


def _camera(doc, where: str, mm: float) -> Camera:
    """One camera from its mapping (module docstring keys)."""
    if not isinstance(doc, Mapping):
        raise ValueError(f"{where}: expected a mapping of the camera's fields, got {type(doc).__name__}")
    K, dist, R, rvec, t = (_field(doc, f, where) for f in ("K", "dist", "R", "rvec", "t"))
    width, height = _field(doc, "width", where), _field(doc, "height", where)
    for name, value in (("K", K), ("t", t), ("width", width), ("height", height)):
        if value is None:
            raise ValueError(f"{where}: missing field {' / '.join(repr(s) for s in _SPELLINGS[name])}")
    if (R is None) == (rvec is None):
        raise ValueError(f"{where}: {'missing field' if R is None else 'both fields'} 'R' (3x3) / 'rvec' "
                         "(Rodrigues): give one")
    if R is None:
        R = rodrigues_to_matrix(rvec, f"{where}: field 'rvec'")
    return build_camera(where, K, R, t, width, height, () if dist is None else dist, CENTRES_AT_INTEGERS, mm)


def _is_camera(doc) -> bool:
    return isinstance(doc, Mapping) and any(k in doc for k in _SPELLINGS["K"])


def _cameras(doc, path: Path, mm: float) -> dict[str, Camera]:
    """Every camera in a document: one camera, a ``cameras`` list or mapping, a list, or a mapping name ->
    camera (entries without a camera matrix, such as FileStorage's calibration_time, ignored)."""
    if _is_camera(doc):
        name = str(doc.get("name", path.stem))
        return {name: _camera(doc, f"{path}: camera {name!r}", mm)}
    if isinstance(doc, Mapping) and "cameras" in doc:
        doc = doc["cameras"]
    if isinstance(doc, list):
        entries = []
        for i, cam in enumerate(doc):
            name = cam.get("name", f"cam{i:03d}") if isinstance(cam, Mapping) else f"cam{i:03d}"
            entries.append((str(name), cam))
    elif isinstance(doc, Mapping):
        entries = [(str(k), v) for k, v in doc.items() if _is_camera(v)]
    else:
        entries = []
    if not entries:
        raise ValueError(f"{path}: no camera found (a mapping with {' / '.join(_SPELLINGS['K'])}, a 'cameras' "
                         "list or mapping, or a mapping of names to cameras)")
    out: dict[str, Camera] = {}
    for name, cam in entries:
        if name in out:
            raise ValueError(f"{path}: camera {name!r} is listed twice")
        out[name] = _camera(cam, f"{path}: camera {name!r}", mm)
    return out


def read_opencv_calibration(path, mm_per_unit: float | str) -> dict[str, Camera]:
    """The cameras of an OpenCV calibration file: FileStorage YAML or JSON, one camera or several.

    The format is told by the contents: JSON when the file starts with '{' or '[', else FileStorage YAML
    (FileStorage's XML is refused). A file holds one camera (its fields at the top level; FileStorage's other
    entries, e.g. ``calibration_time`` or ``avg_reprojection_error``, are ignored), a ``cameras`` list or
    mapping, a top-level list, or a mapping of names to cameras. Fields and spellings: module docstring.
    OpenCV's pixel convention (the top-left pixel's centre at (0, 0)) becomes the Camera's: cx, cy + 0.5.

    Args:
        path: the calibration file (.yml / .yaml / .json).
        mm_per_unit: millimetres per unit of the translations (the unit of the calibration target's square
            size), a positive finite number or "mm", "cm", "m".

    Returns:
        ``{name: Camera}`` in the file's order: a camera's ``name`` field when it has one, else the mapping's
        key, else ``cam000``, ``cam001``, ... in a list, and the file's stem for a file of one camera.

    Raises:
        FileNotFoundError naming the path. ValueError naming the file (and line, for YAML), the camera and
        the field: unparsable contents, a missing or doubly spelt field, R and rvec both or neither, a
        distortion of other than 4 or 5 coefficients (OpenCV's 8, 12 and 14 are refused), and whatever
        ``stage.camera_from_dict`` refuses (K not upper triangular, R not a rotation, a bad image size).

    References:
        The OpenCV documentation: FileStorage ("File Input and Output using XML / YAML / JSON files"),
        calib3d's pinhole model (``projectPoints``) and ``Rodrigues``.
    """
    mm = mm_per_unit_value(mm_per_unit)
    path = existing_path(path, "OpenCV calibration file")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text file (UTF-8)") from None
    head = text.lstrip()
    if head.startswith(("{", "[")):
        doc = read_json(path, "OpenCV calibration file")
    elif head.startswith("<"):
        raise ValueError(f"{path}: OpenCV's XML FileStorage is not supported; write the calibration as YAML "
                         "(cv::FileStorage with a .yml name) or JSON")
    else:
        doc = parse_filestorage_yaml(text, path)
    return _cameras(doc, path, mm)
