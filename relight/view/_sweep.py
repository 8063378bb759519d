"""Rotation sweeps for the viewer's slider: the subject relit under the environment turned about +y in
``frames`` equal steps, tone-mapped at one exposure for every frame (so the frames compare).

* :func:`capture_sweep`: image-based (Debevec et al. 2000) from a texel-space capture
  (``relight.render.image_based_view``: the light weights of every rotation, one pass over the OLAT stack for
  all of them, each texel from its nearest captured view, one ray cast of the camera per group of frames).
  Memory speed.
* :func:`photo_sweep`: the same for one camera's photographs (no geometry,
  ``relight.render.relight_photographs``).
* :func:`maps_sweep`: model-based from a map set (``relight.render.turntable``, which casts the camera's and
  the shadow rays once and reweights the lights per frame), at a low resolution.
* :func:`frames_sweep`: frames that already exist (a ``relight render --frames N`` turntable's PNGs).

:func:`folder_sweeps` finds what a result folder records (its capture, its map set and rig, its camera)
and makes the sweeps it can cheaply, with a note saying why when it cannot.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np

import stage

from ..envmap import EnvMap, bundled_envmap_path, load_envmap
from ..image import subject_exposure, to_uint8, tonemap
from ..materials import MaterialMaps
from ..render import (
    AbstractMethod,
    Dense,
    Reference,
    RenderedFolder,
    Rig,
    image_based_view,
    image_based_weights,
    map_set_capture,
    map_set_rig,
    method_from_name,
    pixel_coverage,
    relight_photographs,
    scaled_camera,
    turntable,
    y_rotations,
)

__all__ = ["DEFAULT_FRAMES", "DEFAULT_SIZE", "MAX_CAPTURE_VALUES", "PREVIEW_ENV_WIDTH", "Sweep", "capture_sweep",
           "folder_sweeps", "frames_sweep", "map_set_sweeps", "maps_sweep", "photo_sweep", "preview_envmap",
           "render_sweeps", "sweep_angles", "sweep_camera"]

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


def sweep_camera(camera: stage.Camera, size: int) -> stage.Camera:
    """``camera`` shrunk to ``size`` pixels on its longer side (never enlarged), its intrinsics scaled with
    it so the picture is the same (``relight.render.scaled_camera``); the pose is unchanged."""
    if not isinstance(size, (int, np.integer)) or size < 8:
        raise ValueError(f"size must be an integer >= 8, got {size!r}")
    return camera if size >= max(camera.width, camera.height) else scaled_camera(camera, int(size))


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
    frames_ = image_based_view(capture, surface, mesh, cam, preview_envmap(env), rotations=y_rotations(angles))
    return _tonemapped(label, angles, frames_, pixel_coverage(mesh, cam), exposure)


def photo_sweep(radiance: np.ndarray, mask: np.ndarray, rig: stage.Rig, env: EnvMap, frames: int = DEFAULT_FRAMES,
                label: str = "photographs, image-based", exposure: float | None = None) -> Sweep:
    """One camera's photographs ``radiance`` [L, H, W, C] (inside ``mask`` [H, W]) relit image-based under
    ``env`` turned by each of :func:`sweep_angles` ``(frames)``; no geometry, the photographs' own size."""
    angles = sweep_angles(frames)
    weights = image_based_weights(preview_envmap(env), rig, y_rotations(angles))
    out, _ = relight_photographs(np.asarray(radiance, np.float32), mask, weights)
    return _tonemapped(label, angles, out, np.asarray(mask, bool).astype(np.float32), exposure)


def maps_sweep(maps: MaterialMaps, surface: stage.Surface, mesh: stage.Mesh, camera: stage.Camera, env: EnvMap,
               method: AbstractMethod | None = None, frames: int = DEFAULT_FRAMES, size: int = DEFAULT_SIZE,
               label: str = "fitted maps, model-based", exposure: float | None = None, rig: stage.Rig | None = None,
               **settings) -> Sweep:
    """The map set ``maps`` (over the texel ``surface``) rendered model-based (``relight.render.turntable``,
    environment mode, one sample a pixel) under ``env`` turned by each of :func:`sweep_angles` ``(frames)``,
    through ``camera`` shrunk to ``size`` px by ``method`` (a ``relight.render`` method Module; default
    ``Rig(rig=rig)``: ``rig`` the rig the maps were captured under); ``settings`` go to the renderer."""
    angles = sweep_angles(frames)
    cam = sweep_camera(camera, size)
    env = preview_envmap(env)
    if rig is not None:
        if method is not None and not (isinstance(method, Rig) and method.rig is None):
            raise ValueError("maps_sweep: rig= is the rig of the method Rig; give it as Rig(rig=...)")
        method = Rig(rig=rig) if method is None else dataclasses.replace(method, rig=rig)
    method = Rig() if method is None else method
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
        return stage.parse_json(path.read_bytes(), path)
    except (OSError, ValueError):
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
        cam = photos.cameras[0]
        values = photos.n_lights * cam.height * cam.width * int(np.asarray(photos.rig.intensity).shape[-1])
        if values > MAX_CAPTURE_VALUES:
            return [], (f"no rotation slider: camera {photos.names[0]}'s photographs hold {values:,} values, more "
                        f"than the {MAX_CAPTURE_VALUES:,} a page's sweep reads whole (run `relight render {folder} "
                        "--frames N` for a turntable)")
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


def _maps_rig(folder: Path, info: dict) -> stage.Rig | None:
    """The rig a map set was captured under (``relight.render.map_set_rig``), else the rig.json of the capture
    it was fitted from or sits in (simulate's truth/ sits inside the capture folder); None if none."""
    try:
        return map_set_rig(folder, info)[0]
    except (OSError, ValueError):
        pass
    cap = map_set_capture(folder)
    if cap is not None and (cap / "rig.json").is_file():
        try:
            return stage.load_rig(cap / "rig.json")
        except (OSError, ValueError):
            return None
    return None


def _maps_sweeps(folder: Path, env, frames, size, camera=None, exposure=None, label=None,
                 method: AbstractMethod | None = None):
    from ..io import load_texel_maps

    tm = load_texel_maps(folder)
    cam = camera if camera is not None else (tm.cameras[0] if tm.cameras else None)
    cap = map_set_capture(folder)
    if cam is None and cap is not None and (cap / "cameras.json").is_file():
        cam = stage.load_cameras(cap / "cameras.json")[0]
    if cam is None:
        return [], f"no rotation slider for {folder.name}/: the map set records no camera to render it from"
    method = Rig() if method is None else method
    if isinstance(method, Rig) and method.rig is None:
        rig = _maps_rig(folder, tm.textures.info)
        if rig is None:
            return [], (f"no rotation slider for {folder.name}/: the map set records no rig (relight render needs "
                        "one for --method rig; render it with --rig or --method dense)")
        method = dataclasses.replace(method, rig=rig)
    return [maps_sweep(tm.maps, tm.surface, tm.mesh, cam, env, method=method, frames=frames, size=size,
                       label=label or "maps, model-based", exposure=exposure)], None


def map_set_sweeps(folder: str | os.PathLike, env: EnvMap, frames: int = DEFAULT_FRAMES, size: int = DEFAULT_SIZE,
                   camera: stage.Camera | None = None, exposure: float | None = None, model: bool = True,
                   method: AbstractMethod | None = None) -> tuple[list[Sweep], str | None]:
    """A map set's sweeps: its capture relit image-based (``relight.render.map_set_capture``, if at hand and at
    most ``MAX_CAPTURE_VALUES``), then, with ``model`` (or when there is no capture), the maps rendered
    model-based (:func:`maps_sweep` by ``method``; default ``Rig()`` through the rig the set records,
    ``relight.render.map_set_rig``). One exposure, the first row's."""
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
        rows, why = _maps_sweeps(folder, env, frames, size, camera, exposure, "the maps rendered model-based",
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
                s, _ = _maps_sweeps(folder / sub, env, frames, size, cam, exposure, label,
                                    Rig(rig=stage.light_stage_x()))
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
        method = method_from_name(str(flags.get("method") or "rig"))
        if isinstance(method, Rig) and flags.get("rig") and Path(str(flags["rig"])).exists():
            p = Path(str(flags["rig"]))
            method = Rig(rig=stage.load_rig(p / "rig.json" if p.is_dir() else p))
        return map_set_sweeps(src, env, frames, size, cam, exposure, model, method)
    return [], "no rotation slider: the render records no input kind"


def render_sweeps(rendered: RenderedFolder, env: EnvMap | str | os.PathLike, frames: int = DEFAULT_FRAMES,
                  size: int = DEFAULT_SIZE) -> tuple[list[Sweep], str | None]:
    """The slider of a ``relight.render.render_folder`` output, at the render's exposure.

    Args:
        rendered: what ``render_folder`` returned.
        env: the render's environment map (or its file; None: the bundled map).
        frames: rotations of the sweep.
        size: longer side of the sweep's frames (px).

    Returns:
        (rows, note): a turntable's own frames (the first camera's PNGs); else a sweep of the input from the
        first camera: a capture or the photographs relit image-based; a map set's own capture relit image-based
        when it is at hand (memory speed), else the maps model-based with the render's method (``Dense`` in
        place of the Monte Carlo ``Reference``, which would cost more than the render itself).
    """
    env = env if isinstance(env, EnvMap) else _env(env)
    src, exposure = rendered.source, rendered.exposure
    if len(rendered.angles_deg) > 1:
        if rendered.kind == "photos":
            label = f"rendered turntable of {rendered.cameras[0]}"
        else:
            label = f"rendered turntable, method {rendered.resolved['method']}"
        return [frames_sweep(rendered.previews, rendered.angles_deg, label)], None
    if "photos" in src:
        view = next(src["photos"].iter_views())
        return [photo_sweep(view.radiance, view.mask, src["photos"].rig, env, frames,
                            f"photographs of {view.name} relit image-based", exposure)], None
    camera = rendered.cameras[0]
    if "capture" in src:
        return [capture_sweep(src["capture"], src["surface"], src["mesh"], camera, env, frames, size,
                              "the capture relit image-based", exposure)], None
    method = src["method"]
    if map_set_capture(src["folder"]) is not None:
        rows, note = map_set_sweeps(src["folder"], env, frames, size, camera, exposure, model=False, method=method)
        if rows:
            return rows, note
    method = Dense() if isinstance(method, Reference) else method
    settings = {"eta": src["eta"]} if "eta" in src else {}
    return [maps_sweep(src["maps"], src["surface"], src["mesh"], camera, env, method=method, frames=frames,
                       size=size, exposure=exposure, label=f"the maps rendered model-based, method {method.name}",
                       **settings)], None
