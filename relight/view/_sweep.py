"""Rotation sweeps for the viewer's slider: the subject relit under the environment turned about +y in
``frames`` equal steps, tone-mapped at one exposure for every frame (so the frames compare).

* :func:`capture_sweep`: image-based (Debevec et al. 2000) from a texel-space capture: the light weights of
  every rotation (``relight.envmap.rotation_sweep_weights``), one pass over the OLAT stack for all of them
  (``relight.render.relight_olat_sweep``), each texel from its nearest captured view
  (``relight.render.nearest_view``), and one ray cast of the camera for all frames. Memory speed.
* :func:`photo_sweep`: the same for one camera's photographs (no geometry).
* :func:`maps_sweep`: model-based from a map set (``relight.render.turntable``, which casts the camera's and
  the shadow rays once and reweights the lights per frame), at a low resolution.
* :func:`frames_sweep`: frames that already exist (a ``relight render --frames N`` turntable's PNGs).

:func:`folder_sweeps` finds what a result folder records (its capture, its map set and rig, its camera)
and makes the sweeps it can cheaply, with a note saying why when it cannot.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

import stage

from ..envmap import bundled_envmap_path, load_envmap, rotation_matrix, rotation_sweep_weights
from ..envmap._latlong import EnvMap
from ..image import dilate, subject_exposure, texture_view, to_uint8, tonemap
from ..materials import MaterialMaps
from ..render import nearest_view, pixel_coverage, relight_olat_sweep, turntable

__all__ = ["DEFAULT_FRAMES", "DEFAULT_SIZE", "MAX_CAPTURE_VALUES", "PREVIEW_ENV_WIDTH", "Sweep", "capture_sweep",
           "folder_sweeps", "frames_sweep", "map_set_capture", "map_set_sweeps", "maps_sweep", "photo_sweep",
           "preview_envmap", "sweep_angles", "sweep_camera"]

# Rotations of a sweep and the longer side (pixels) of its frames: 24 steps of 15 degrees, small frames (the
# slider shows the light moving; the full-size render is the command's own output).
DEFAULT_FRAMES = 24
DEFAULT_SIZE = 160
# The largest capture (views x lights x texels x channels, float32) a folder's sweep loads whole: 64 Mi values,
# 256 MiB. Above it the page says so instead of reading a capture that the fit streams block by block.
MAX_CAPTURE_VALUES = 1 << 26
# The environment is area-averaged down to at most this many pixels across before a sweep's light weights: the
# weights are integrals over each light's cell (solid-angle weighted, so the map's integral is kept exactly). The
# bundled 1024 x 512 map costs 2.2 s of Voronoi weights a rotation for the Light Stage X's 346 lights (0.25 s for
# 42) on 2 busy CPU cores; 256 x 128 costs 0.14 s (0.04 s).
PREVIEW_ENV_WIDTH = 256
# Gutter texels filled around the UV charts before the lookup (relight.render's image-based view does the same).
_DILATE = 2


class Sweep(NamedTuple):
    """One row of the slider: ``frames`` uint8 [K, H, W, 3] (sRGB) at ``angles_deg`` [K], tone-mapped at
    ``exposure`` stops (ACES filmic), with a ``label`` saying what it shows."""

    label: str
    angles_deg: np.ndarray
    frames: np.ndarray
    exposure: float


def sweep_angles(frames: int) -> np.ndarray:
    """[frames] rotations in degrees: 0, 360/frames, ... (a full turn, the last step short of 360)."""
    if not isinstance(frames, (int, np.integer)) or isinstance(frames, bool) or frames < 1:
        raise ValueError(f"frames must be an integer >= 1, got {frames!r}")
    return 360.0 * np.arange(int(frames)) / int(frames)


def _rotations(angles) -> np.ndarray:
    """[K, 3, 3] rotations about +y by ``angles`` (degrees): light from d arrives from R d."""
    return np.stack([np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(a)), np.float64)
                     for a in np.asarray(angles, np.float64)])


def sweep_camera(camera: stage.Camera, size: int) -> stage.Camera:
    """``camera`` shrunk to ``size`` pixels on its longer side (never enlarged), its intrinsics scaled with
    it so the picture is the same; the pose is unchanged."""
    import jax.numpy as jnp

    if not isinstance(size, (int, np.integer)) or size < 8:
        raise ValueError(f"size must be an integer >= 8, got {size!r}")
    s = size / max(camera.width, camera.height)
    if s >= 1.0:
        return camera
    w, h = max(1, round(camera.width * s)), max(1, round(camera.height * s))
    scale = np.diag([w / camera.width, h / camera.height, 1.0])
    K = jnp.asarray(scale @ np.asarray(camera.K, np.float64), camera.K.dtype)
    return stage.Camera(K=K, R=camera.R, t=camera.t, width=w, height=h, orthographic=camera.orthographic)


def preview_envmap(env: EnvMap, width: int = PREVIEW_ENV_WIDTH) -> EnvMap:
    """``env`` area-averaged by a whole factor down to at most ``width`` pixels across (unchanged when already
    that small): each block's mean weighted by its rows' solid angles, so the integral of radiance over the
    sphere, and each light's cell integral to within a block, are kept."""
    rad = np.asarray(env.radiance, np.float64)
    H, W, C = rad.shape
    f = max(1, W // int(width))
    while f > 1 and (H % f or W % f):
        f -= 1
    if f == 1:
        return env
    theta = (np.arange(H) + 0.5) / H * np.pi  # row centres' polar angle
    w = np.sin(theta)[:, None, None]  # a row's solid angle per pixel is proportional to sin(theta)
    num = (rad * w).reshape(H // f, f, W // f, f, C).sum(axis=(1, 3))
    den = np.broadcast_to(w, (H, W, 1)).reshape(H // f, f, W // f, f, 1).sum(axis=(1, 3))
    return EnvMap(np.asarray(num / den, np.float32))


def _tonemapped(label: str, angles, frames: np.ndarray, coverage, exposure: float | None) -> Sweep:
    frames = np.asarray(frames, np.float32)
    if frames.shape[-1] == 1:
        frames = np.repeat(frames, 3, -1)
    elif frames.shape[-1] != 3:
        frames = np.repeat(frames.mean(-1, keepdims=True), 3, -1)
    frames = np.where(np.isfinite(frames), frames, 0.0).astype(np.float32)
    if exposure is None:
        exposure = subject_exposure(frames, None if coverage is None else np.asarray(coverage)[None])
    out = to_uint8(tonemap(frames, exposure=float(exposure), curve="filmic"))
    return Sweep(str(label), np.asarray(angles, np.float64), out, float(exposure))


def capture_sweep(capture: stage.Capture, surface: stage.Surface, mesh: stage.Mesh, camera: stage.Camera,
                  env: EnvMap, frames: int = DEFAULT_FRAMES, size: int = DEFAULT_SIZE,
                  label: str = "capture, image-based", exposure: float | None = None) -> Sweep:
    """The texel-space ``capture`` (over ``surface``'s samples) relit image-based under ``env`` turned by
    each of :func:`sweep_angles` ``(frames)`` and seen through ``camera`` shrunk to ``size`` px
    (:func:`sweep_camera`); ``exposure`` None: the subject's (``relight.image.subject_exposure``)."""
    angles = sweep_angles(frames)
    cam = sweep_camera(camera, size)
    env = preview_envmap(env)
    rig = capture.rig
    weights = rotation_sweep_weights(env, rig.directions, rig.center_irradiance, _rotations(angles))  # [K, L, C]
    relit = np.asarray(relight_olat_sweep(capture.radiance, weights))  # [K, V, P, C]
    relit = relit[:, nearest_view(capture, cam), np.arange(surface.num_samples)]  # [K, P, C]
    H, W = surface.resolution
    covered = np.zeros((H, W), bool)
    covered.reshape(-1)[np.asarray(surface.texel_index)] = True
    textures = {str(k): dilate(surface.to_texture(relit[k]), covered, _DILATE) for k in range(len(angles))}
    views = texture_view(mesh, cam, textures)  # one ray cast for every frame
    return _tonemapped(label, angles, np.stack([views[str(k)] for k in range(len(angles))]),
                       pixel_coverage(mesh, cam), exposure)


def photo_sweep(radiance: np.ndarray, mask: np.ndarray, rig: stage.Rig, env: EnvMap, frames: int = DEFAULT_FRAMES,
                label: str = "photographs, image-based", exposure: float | None = None) -> Sweep:
    """One camera's photographs ``radiance`` [L, H, W, C] (inside ``mask`` [H, W]) relit image-based under
    ``env`` turned by each of :func:`sweep_angles` ``(frames)``; no geometry, the photographs' own size."""
    angles = sweep_angles(frames)
    radiance = np.asarray(radiance, np.float32)
    L, H, W, C = radiance.shape
    env = preview_envmap(env)
    weights = np.asarray(rotation_sweep_weights(env, rig.directions, rig.center_irradiance, _rotations(angles)))
    if C != weights.shape[-1]:
        weights = weights.mean(-1, keepdims=True)
    relit = np.asarray(relight_olat_sweep(radiance.reshape(L, H * W, C), weights.astype(np.float32)))
    inside = np.asarray(mask, bool)
    out = np.where(inside[None, ..., None], relit.reshape(len(angles), H, W, C), 0.0)
    return _tonemapped(label, angles, out, inside.astype(np.float32), exposure)


def maps_sweep(maps: MaterialMaps, surface: stage.Surface, mesh: stage.Mesh, camera: stage.Camera, env: EnvMap,
               rig: stage.Rig | None = None, method: str = "rig", frames: int = DEFAULT_FRAMES,
               size: int = DEFAULT_SIZE, label: str = "fitted maps, model-based", exposure: float | None = None,
               **settings) -> Sweep:
    """The map set ``maps`` (over the texel ``surface``) rendered model-based (``relight.render.turntable``,
    environment mode, one sample a pixel) under ``env`` turned by each of :func:`sweep_angles` ``(frames)``,
    through ``camera`` shrunk to ``size`` px; ``rig`` for ``method="rig"`` (the rig the maps were captured
    under); ``settings`` go to the renderer."""
    angles = sweep_angles(frames)
    cam = sweep_camera(camera, size)
    env = preview_envmap(env)
    if method == "rig" and rig is not None:
        settings["rig"] = rig
    imgs = list(turntable(maps, surface, mesh, cam, env, frames=int(frames), mode="envmap", method=method,
                          supersample=1, background=False, **settings))
    return _tonemapped(label, angles, np.stack(imgs), pixel_coverage(mesh, cam), exposure)


def frames_sweep(paths, angles_deg, label: str = "rendered frames") -> Sweep:
    """Frames already on disk (``relight render --frames N``'s PNGs, in rotation order) as a sweep: read as
    they are (their tone mapping is the render's)."""
    from ..io import read_png

    imgs = []
    for p in paths:
        img = np.asarray(read_png(p))
        img = img[..., None] if img.ndim == 2 else img
        img = np.repeat(img[..., :1], 3, -1) if img.shape[-1] < 3 else img[..., :3]
        imgs.append(img.astype(np.uint8))
    if len({i.shape for i in imgs}) != 1:
        raise ValueError("frames_sweep: the frames differ in size")
    return Sweep(str(label), np.asarray(angles_deg, np.float64), np.stack(imgs), float("nan"))


# ---------------------------------------------------------------- what a folder records


def _json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return None


def _settings(folder: Path) -> dict:
    doc = _json(folder / "settings.json")
    return doc if isinstance(doc, dict) else {}


def _env(spec) -> EnvMap:
    return load_envmap(Path(spec) if spec else bundled_envmap_path())


def _capture_values(folder: Path) -> int | None:
    """V x L x texels x C of a texel capture folder or store, from its description alone (None: unknown)."""
    from ..io import is_capture_store, open_capture, open_capture_store

    try:
        reader = open_capture_store(folder) if (is_capture_store(folder) and not (folder / "capture.json").exists()) \
            else open_capture(folder)
        V, L = reader.n_views, reader.n_lights
        n = int(np.prod(reader.sample_shape))
        return int(V * L * n * reader.n_channels)
    except (OSError, ValueError, AttributeError):
        return None


def _camera_from(doc) -> stage.Camera | None:
    if not isinstance(doc, dict):
        return None
    try:
        return stage.camera_from_dict(doc)
    except (ValueError, TypeError, KeyError):
        return None


def _capture_sweeps(folder: Path, env, frames, size, camera=None, exposure=None, label=None):
    from ..io import is_photo_capture, load_texel_capture, read_photo_capture

    if is_photo_capture(folder):
        photos = read_photo_capture(folder)
        view = next(photos.iter_views())
        return [photo_sweep(view.radiance, view.mask, photos.rig, env, frames,
                            label or f"photographs of {view.name}, image-based", exposure)], None
    values = _capture_values(folder)
    if values is not None and values > MAX_CAPTURE_VALUES:
        return [], (f"no rotation slider: the capture {folder} holds {values:,} values, more than the "
                    f"{MAX_CAPTURE_VALUES:,} a page's sweep reads whole (run `relight render {folder} --frames N` "
                    "for a turntable)")
    try:
        capture, surface, mesh, _ = load_texel_capture(folder)
    except ValueError as err:  # a capture folder without the texel metadata a surface is rebuilt from
        return [], f"no rotation slider: {err}"
    cam = camera if camera is not None else capture.cameras[0]
    return [capture_sweep(capture, surface, mesh, cam, env, frames, size, label or "capture, image-based",
                          exposure)], None


def map_set_capture(folder: str | os.PathLike) -> Path | None:
    """The capture folder or store a map set was fitted from (maps.json ``metadata.capture``, absolute or
    relative to the set; a ``truth/`` inside a capture: that capture), if it is still there; else None."""
    from ..io import is_capture_store

    folder = Path(folder)
    meta = (_json(folder / "maps.json") or {}).get("metadata") or {}
    cands = [folder / meta["capture"]] if isinstance(meta.get("capture"), str) and meta["capture"] else []
    if folder.name == "truth":
        cands.append(folder.parent)
    for c in cands:
        if (c / "capture.json").is_file() or is_capture_store(c):
            return c
    return None


def _maps_rig(folder: Path, textures, recorded):
    """The rig a map set was captured under: the set's rig.json, its capture's, or its parent capture's
    (simulate's truth/ sits inside the capture folder)."""
    if recorded is not None:
        return recorded
    cap = map_set_capture(folder)
    if cap is not None and (cap / "rig.json").is_file():
        try:
            return stage.load_rig(cap / "rig.json")
        except (OSError, ValueError):
            return None
    return None


def _maps_sweeps(folder: Path, env, frames, size, camera=None, exposure=None, label=None, rig=None,
                 method="rig"):
    from ..io import load_texel_maps

    tm = load_texel_maps(folder)
    cam = camera if camera is not None else (tm.cameras[0] if tm.cameras else None)
    cap = map_set_capture(folder)
    if cam is None and cap is not None and (cap / "cameras.json").is_file():
        cam = stage.load_cameras(cap / "cameras.json")[0]
    if cam is None:
        return [], f"no rotation slider for {folder.name}/: the map set records no camera to render it from"
    rig = rig if rig is not None else _maps_rig(folder, tm.textures, tm.rig)
    if method == "rig" and rig is None:
        return [], (f"no rotation slider for {folder.name}/: the map set records no rig (relight render needs one "
                    "for --method rig; render it with --rig or --method dense)")
    return [maps_sweep(tm.maps, tm.surface, tm.mesh, cam, env, rig=rig, method=method, frames=frames, size=size,
                       label=label or "maps, model-based", exposure=exposure)], None


def map_set_sweeps(folder: str | os.PathLike, env: EnvMap, frames: int = DEFAULT_FRAMES, size: int = DEFAULT_SIZE,
                   camera: stage.Camera | None = None, exposure: float | None = None, model: bool = True,
                   rig: stage.Rig | None = None, method: str = "rig") -> tuple[list[Sweep], str | None]:
    """A map set's sweeps: its capture relit image-based (:func:`map_set_capture`, if at hand and at most
    ``MAX_CAPTURE_VALUES``), then, with ``model`` (or when there is no capture), the maps rendered model-based
    (:func:`maps_sweep` through ``rig``, else the rig the set records). One exposure, the first row's."""
    folder = Path(folder)
    sweeps, notes = [], []
    cap = map_set_capture(folder)
    if cap is not None:
        rows, why = _capture_sweeps(cap, env, frames, size, camera, exposure, "the capture it was fitted from, "
                                    "relit image-based")
        sweeps += rows
        notes += [why] if why else []
    if model or not sweeps:
        if sweeps and exposure is None:
            exposure = sweeps[0].exposure
        rows, why = _maps_sweeps(folder, env, frames, size, camera, exposure, "the maps rendered model-based", rig,
                                 method)
        sweeps += rows
        notes += [why] if why else []
    return sweeps, (None if sweeps else "; ".join(notes) or "no rotation slider")


def folder_sweeps(folder: str | os.PathLike, envmap: str | os.PathLike | None = None, frames: int = DEFAULT_FRAMES,
                  size: int = DEFAULT_SIZE, model: bool = True) -> tuple[list[Sweep], str | None]:
    """The sweeps a result folder supports, found from what it records, and None or a note saying why there
    is no slider. A capture folder or store (``relight simulate`` / ``convert``): image-based; a map set
    (``relight fit``, ``truth/``): :func:`map_set_sweeps` (its capture image-based, and with ``model`` the
    maps model-based through its rig); a ``relight render`` output: its own frames for a turntable, else a
    sweep of its input from its camera; a ``relight demo`` output: its truth and fitted maps through the Light
    Stage X from its camera. ``envmap``: the map (default: the one the folder records, else the bundled map)."""
    from ..io import is_capture_store, is_map_set

    folder = Path(folder)
    settings = _settings(folder)
    command = settings.get("command")
    resolved = settings.get("resolved") or {}
    if command == "relight render":
        return _render_sweeps(folder, settings, envmap, frames, size, model)
    if command == "relight demo":
        env = _env(envmap or settings.get("envmap"))
        cam = _camera_from(settings.get("camera"))
        if cam is None:
            return [], "no rotation slider: this demo folder records no camera (written by an older relight)"
        sweeps, exposure = [], None
        for sub, label in (("truth", "truth maps, model-based"), ("maps", "fitted maps, model-based")):
            if is_map_set(folder / sub):  # one exposure, the first's, so the two rows compare
                s, _ = _maps_sweeps(folder / sub, env, frames, size, cam, exposure, label, rig=stage.light_stage_x())
                sweeps += s
                exposure = sweeps[0].exposure if sweeps else None
        return sweeps, None if sweeps else "no rotation slider: no maps/ or truth/ map set here"
    env = _env(envmap or resolved.get("envmap"))
    if (folder / "capture.json").is_file() or is_capture_store(folder):
        return _capture_sweeps(folder, env, frames, size)
    if is_map_set(folder):
        return map_set_sweeps(folder, env, frames, size, model=model)
    return [], "no rotation slider: this folder holds no capture, map set or render this viewer knows"


def _render_sweeps(folder: Path, settings: dict, envmap, frames: int, size: int, model: bool):
    resolved = settings.get("resolved") or {}
    flags = settings.get("flags") or {}
    rot = resolved.get("rotations_deg") or []
    outputs = resolved.get("outputs") or []
    if len(rot) > 1 and outputs:
        pngs = [folder / (str(o)[:-4] + ".png") for o in outputs[:len(rot)]]
        if all(p.is_file() for p in pngs):
            return [frames_sweep(pngs, rot, f"rendered turntable ({resolved.get('method', 'render')})")], None
    env = _env(envmap or resolved.get("envmap"))
    src = Path(str(flags.get("input", "")))
    if not src.is_absolute() and not src.is_dir():
        src = folder.parent / src
    if not src.is_dir():
        return [], f"no rotation slider: the render's input {flags.get('input')!r} is no longer at hand"
    exposure = resolved.get("preview_exposure_stops")
    exposure = float(exposure) if isinstance(exposure, (int, float)) and flags.get("exposure") is not None else None
    cam = _camera_from(resolved.get("camera")) or _camera_from((resolved.get("cameras") or [None])[0])
    kind = resolved.get("input_kind")
    if kind in ("capture", "photos"):
        return _capture_sweeps(src, env, frames, size, cam, exposure, "input capture, image-based")
    if kind == "maps":
        method = str(flags.get("method") or "rig")
        rig = None
        if method == "rig" and flags.get("rig") and Path(str(flags["rig"])).exists():
            p = Path(str(flags["rig"]))
            rig = stage.load_rig(p / "rig.json" if p.is_dir() else p)
        return map_set_sweeps(src, env, frames, size, cam, exposure, model, rig, method)
    return [], "no rotation slider: the render records no input kind"
