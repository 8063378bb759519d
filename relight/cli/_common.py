"""Pieces the ``relight`` subcommands share: parsing ``--rig`` / ``--camera`` /
``--mesh``, rebuilding a texel surface from what a capture or map set
recorded, progress bars, settings.json and previews."""

from __future__ import annotations

import json
import os
from pathlib import Path

import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

import stage

from ..io._atomic import atomic_write_bytes
from ..io._texture_set import _jsonable as jsonable  # noqa: F401  (one JSON conversion for maps.json and the CLI)


class CLIError(Exception):
    """A problem with the command line or its inputs: printed as
    ``relight <command>: error: <message>``, exit code 1."""


def bar(total, desc, quiet):
    return tqdm(total=total, desc=desc, unit="it", leave=False, disable=quiet, dynamic_ncols=True)




def write_json(path: Path, obj) -> None:
    text = json.dumps(jsonable(obj), indent=2, allow_nan=False) + "\n"
    atomic_write_bytes(path, lambda fh: fh.write(text.encode()))


def write_settings(out: Path, command: str, args, **resolved) -> None:
    """settings.json: the command, every flag as given/defaulted, and the resolved values."""
    flags = {k: v for k, v in vars(args).items() if k not in ("func", "command")}
    write_json(Path(out) / "settings.json", {"command": f"relight {command}", "flags": flags, "resolved": resolved})


def read_json(path: Path, what: str):
    if not path.is_file():
        raise FileNotFoundError(f"{path}: missing ({what})")
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise CLIError(f"{path}: invalid JSON ({err})") from None


# ------------------------------------------------------------------ meshes


def mesh_spec(path: str | None) -> dict:
    """How to load the mesh again: the bundled head (scaled to mm, centred) or a file (mm, as is)."""
    if path is None or path in ("head", "bundled"):
        return {"bundled": "head", "path": str(stage.head_mesh_path()), "scale": stage.HEAD_SCALE_MM, "center": True}
    p = Path(path).resolve()
    if not p.is_file():
        raise FileNotFoundError(f"{path}: mesh file not found")
    return {"bundled": None, "path": str(p), "scale": 1.0, "center": False}


def load_mesh(spec: dict, where: str = "") -> stage.Mesh:
    if not isinstance(spec, dict) or "path" not in spec:
        raise CLIError(f"{where}: no mesh recorded (expected a 'surface' entry with the mesh 'path')")
    if spec.get("bundled") == "head":
        return stage.load_head()
    path = Path(spec["path"])
    if not path.is_file():
        raise FileNotFoundError(f"{path}: mesh file not found (recorded in {where})")
    return stage.load_mesh(path, scale=float(spec.get("scale", 1.0)), center=bool(spec.get("center", False)),
                           require_uv=True)


def texel_surface(spec: dict, resolution, where: str = ""):
    """(mesh, full texel surface) for a recorded mesh spec and texel resolution."""
    mesh = load_mesh(spec, where)
    try:
        res = tuple(int(r) for r in (resolution if np.ndim(resolution) else (resolution, resolution)))
    except (TypeError, ValueError):
        raise CLIError(f"{where}: bad texel resolution {resolution!r}") from None
    return mesh, stage.texel_samples(mesh, res)


# ------------------------------------------------------------------ rigs


def parse_rig(spec: str) -> tuple[stage.Rig, str]:
    """``lsx`` (ICT Light Stage X, 346 near-field lights), ``dome:N`` (N distant
    lights: a geodesic dome when N = 10 * 4^s + 2, else a Fibonacci sphere) or a
    rig.json file (a capture folder's rig: positions/directions + intensities)."""
    s = spec.strip()
    if s.lower() in ("lsx", "light_stage_x", "lightstage"):
        return stage.light_stage_x(), "ICT Light Stage X (346 lights, near field)"
    if s.lower().startswith("dome:"):
        try:
            n = int(s[5:])
        except ValueError:
            raise CLIError(f"--rig {spec}: dome:N needs an integer light count N") from None
        if n < 4:
            raise CLIError(f"--rig {spec}: a dome needs at least 4 lights")
        for sub in range(6):
            if 10 * 4**sub + 2 == n:
                return stage.geodesic_dome(sub), f"geodesic dome, {n} distant lights (subdivision {sub})"
        return stage.fibonacci_sphere(n), f"Fibonacci sphere, {n} distant lights"
    p = Path(s)
    if not p.exists():
        raise CLIError(f"--rig {spec}: not lsx, dome:N or an existing rig file")
    if p.is_dir():
        p = p / "rig.json"
    return rig_from_json(read_json(p, "rig file"), p), f"rig file {p}"


def rig_to_json(rig: stage.Rig) -> dict:
    return {"positions": np.asarray(rig.position, np.float64), "intensities": np.asarray(rig.intensity, np.float64),
            "solid_angles": np.asarray(rig.solid_angle, np.float64), "near_field": bool(rig.near_field),
            "units": {"positions": "mm (distant lights: direction x radius)",
                      "intensities": "radiant intensity (near field) or irradiance at normal incidence (distant)"}}


def rig_from_json(doc, where) -> stage.Rig:
    if not isinstance(doc, dict):
        raise CLIError(f"{where}: a rig file must be a JSON object")
    near = bool(doc.get("near_field", "positions" in doc and "directions" not in doc))
    key = "positions" if "positions" in doc else "directions" if "directions" in doc else None
    if key is None:
        raise CLIError(f"{where}: rig needs 'positions' or 'directions' ([L, 3])")
    try:
        pos = np.asarray(doc[key], np.float64)
        inten = np.asarray(doc.get("intensities", 1.0), np.float64)
        if key == "directions":
            pos = pos / np.linalg.norm(pos, axis=1, keepdims=True) * 1000.0
        rig = stage.make_rig(pos, inten, near_field=near)
    except (ValueError, TypeError, IndexError) as err:
        raise CLIError(f"{where}: bad rig ({err})") from None
    if "solid_angles" in doc and len(doc["solid_angles"]) == rig.num_lights:
        rig = stage.Rig(rig.position, rig.intensity, jnp.asarray(doc["solid_angles"], jnp.float32), rig.near_field)
    return rig


# ------------------------------------------------------------------ cameras

FRONT_FOV_DEG = 11.0


def front_camera(mesh: stage.Mesh, size: int) -> stage.Camera:
    """A telephoto camera on +z framing the mesh (for the bundled head: 1.3 m away, 11 degrees, as the demo)."""
    v = np.asarray(mesh.vertices, np.float64)
    lo, hi = v.min(0), v.max(0)
    c = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    dist = 1.15 * max(half[0], half[1]) / np.tan(np.deg2rad(FRONT_FOV_DEG / 2)) + half[2]
    return stage.look_at((c[0], c[1], c[2] + dist), tuple(c), fov_deg=FRONT_FOV_DEG, width=size, height=size)


def parse_cameras(spec: str | None, mesh: stage.Mesh, size: int, default=None) -> tuple[stage.Camera, ...]:
    """``front`` (see :func:`front_camera`) or a cameras.json (``stage.save_cameras`` format)."""
    if spec is None:
        if default is not None:
            return tuple(default)
        spec = "front"
    if spec == "front":
        return (front_camera(mesh, size),)
    p = Path(spec)
    if p.is_dir():
        p = p / "cameras.json"
    if not p.is_file():
        raise FileNotFoundError(f"--camera {spec}: not 'front' and no such cameras file")
    doc = read_json(p, "cameras file")
    if isinstance(doc, list):  # a capture folder's cameras.json
        return cameras_from_json(doc, p)
    return stage.load_cameras(p)


def camera_to_json(cam: stage.Camera, name: str) -> dict:
    return {"name": name, "model": "orthographic" if cam.orthographic else "pinhole", "width": cam.width,
            "height": cam.height, "K": np.asarray(cam.K, np.float64), "R": np.asarray(cam.R, np.float64),
            "t": np.asarray(cam.t, np.float64), "convention": "opencv", "units": "mm"}


def cameras_from_json(doc, where) -> tuple[stage.Camera, ...]:
    out = []
    for i, c in enumerate(doc):
        try:
            K, R, t = (np.asarray(c[k], np.float64) for k in ("K", "R", "t"))
            out.append(stage.Camera(K=jnp.asarray(K, jnp.float32), R=jnp.asarray(R, jnp.float32),
                                    t=jnp.asarray(t, jnp.float32), width=int(c["width"]), height=int(c["height"]),
                                    orthographic=c.get("model", "pinhole") == "orthographic"))
        except (KeyError, TypeError, ValueError) as err:
            raise CLIError(f"{where}: camera {i}: missing or bad field ({err})") from None
    if not out:
        raise CLIError(f"{where}: no cameras")
    return tuple(out)


# ------------------------------------------------------------------ previews


def auto_exposure(img: np.ndarray) -> float:
    """Stops that bring the 99th percentile of the positive pixels to 1."""
    pos = np.asarray(img)[np.asarray(img) > 0]
    return -float(np.log2(max(np.percentile(pos, 99), 1e-6))) if pos.size else 0.0


def write_preview(path: Path, img: np.ndarray, exposure: float | None = None, curve: str = "filmic") -> None:
    from ..io._png import write_png
    from ..image._tonemap import to_uint8, tonemap

    img = np.asarray(img, np.float32)
    if img.ndim == 2:
        img = img[..., None]
    if img.shape[-1] == 1:
        img = np.repeat(img, 3, -1)
    elif img.shape[-1] == 2:
        img = np.concatenate([img, np.zeros_like(img[..., :1])], -1)
    exposure = auto_exposure(img) if exposure is None else exposure
    write_png(path, to_uint8(tonemap(img, exposure=exposure, curve=curve)))


def ensure_out(out: str | os.PathLike) -> Path:
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out}: exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    return out
