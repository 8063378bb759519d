"""Relighting an input folder into an output folder (what ``relight render`` does): a texel-space
capture relit image-based and seen through cameras, a camera-space photo capture relit image-based
camera by camera (no geometry), or a fitted map set rendered model-based with a method Module.

:func:`render_folder` writes ``relit.exr`` (R, G, B, A: radiance premultiplied by A, the fraction of
the pixel the subject covers; the run's settings in the header) and ``relit.png`` (tone-mapped at one
exposure for every frame and camera), ``relit_000.exr`` ... for a turntable, one folder per camera
when there are several (``cam000/``, ...; a photo capture: one per camera name), and returns what
settings.json records. The helpers it uses are public: :func:`input_kind`, :func:`map_set_capture`,
:func:`map_set_rig`, :func:`subsurface_settings`, :func:`render_cameras`, :func:`unseen_warnings`.
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np

import skin_bssrdf
import stage

from ..envmap._latlong import EnvMap
from ..materials._maps import SUBSURFACE
from ._abstract import AbstractMethod
from ._coverage import environment_behind, pixel_coverage, texel_fraction, uncovered_pixels
from ._image_based import image_based_view, image_based_weights, relight_photographs, seen_texels
from ._rig import Rig
from ._view import render_view, scaled_camera, y_rotations

__all__ = ["BACKGROUNDS", "FRONT_SIZE", "UNSEEN_WARN", "RenderedFolder", "input_kind", "map_set_capture",
           "map_set_rig", "render_cameras", "render_folder", "subsurface_settings", "unseen_warnings"]

# What is behind the subject in the outputs: black, the (rotated) environment composited by coverage,
# or a transparent background (black in the EXR, an alpha channel in the PNG).
BACKGROUNDS = ("black", "env", "alpha")
# The 'front' camera's pixels (N x N) when no image size is given.
FRONT_SIZE = 256
# Fraction of the subject's pixels on texels without data (no camera saw them: a capture's unseen texels, a
# map set's filled or missing ones) from which a warning is due (one pixel in a thousand: below that,
# silhouette pixels whose rays graze the texel grid's gutter).
UNSEEN_WARN = 1e-3


class RenderedFolder(NamedTuple):
    """What :func:`render_folder` wrote and settings.json records.

    Attributes:
        kind: the input kind, "capture", "photos" or "maps".
        resolved: the resolved settings (JSON-ready: envmap, method, rotations, cameras, exposure,
            outputs, seconds, ...).
        outputs: the EXR files written, relative to the output folder.
        previews: the PNG previews of the first camera, one per frame (paths in the output folder).
        angles_deg: [K] the environment rotations about +y.
        exposure: the previews' exposure in stops.
        cameras: the render cameras (a photo capture: its own, by name).
        warnings: lines to show the user (subject pixels on texels without data).
        summary: one line saying what was written.
        source: what a viewer's sweep relights: the capture (``capture``, ``surface``, ``mesh``), the
            photographs (``photos``), or the map set (``maps``, ``surface``, ``mesh``, ``method``,
            ``eta``, ``folder``, ``filled``: whether it fills texels no camera saw).
    """

    kind: str
    resolved: dict
    outputs: list
    previews: list
    angles_deg: np.ndarray
    exposure: float
    cameras: tuple
    warnings: list
    summary: str
    source: dict


def input_kind(path: str | os.PathLike) -> str:
    """The kind of a render input folder.

    Args:
        path: a capture folder (capture.json) or a fitted map set (maps.json).

    Returns:
        "capture" (texel space), "photos" (a camera-space photo capture) or "maps".
    """
    from ..io import is_map_set, is_photo_capture

    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such input folder")
    if not path.is_dir():
        raise ValueError(f"{path}: INPUT must be a folder (a capture or a fitted map set)")
    if (path / "capture.json").is_file():
        return "photos" if is_photo_capture(path) else "capture"
    if (path / "maps.json").is_file():
        if not is_map_set(path):
            raise ValueError(f"{path / 'maps.json'}: not a relight map set (format is not 'relight-maps')")
        return "maps"
    raise ValueError(f"{path}: neither a capture folder (no capture.json) nor a fitted map set (no maps.json)")


def _json(path: Path):
    try:
        return stage.parse_json(path.read_bytes(), path)
    except (OSError, ValueError):
        return None


def map_set_capture(folder: str | os.PathLike) -> Path | None:
    """The capture a map set was fitted from, if it is still there.

    Args:
        folder: a map set (maps.json).

    Returns:
        The capture folder or store maps.json's ``metadata.capture`` names (absolute or relative to the
        set; a ``truth/`` inside a capture: that capture), or None.
    """
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


def map_set_rig(folder: str | os.PathLike, info: dict | None = None) -> tuple[stage.Rig, str]:
    """The rig a map set was captured under (what ``Rig`` renders it with).

    Args:
        folder: a map set (maps.json).
        info: its maps.json document, if already read.

    Returns:
        (rig, description): the set's own rig.json (maps.json ``metadata.rig``), else the rig.json of
        the capture folder the set records (``metadata.capture``, absolute or relative to the set).
        ValueError when there is none (the Light Stage X is not the capture's rig).
    """
    folder = Path(folder)
    info = _json(folder / "maps.json") if info is None else info
    meta = (info or {}).get("metadata", {}) or {}
    own = folder / str(meta["rig"]) if meta.get("rig") else None
    if own is not None and own.is_file():
        return stage.load_rig(own), f"the capture's rig ({own})"
    cap = meta.get("capture")
    if isinstance(cap, str) and cap:
        rig = folder / cap / "rig.json"  # an absolute path stays as it is; a relative one is the map set's
        if rig.is_file():
            return stage.load_rig(rig), f"the rig of the capture it came from ({rig})"
    raise ValueError(f"{folder}: --method rig needs the rig the maps were captured under, and this map set has no "
                     "rig.json (nor records a capture folder holding one); pass --rig <capture>/rig.json (or lsx | "
                     "dome:N), or render with a method that needs no rig (--method dense)")


def subsurface_settings(folder: str | os.PathLike, info: dict, maps) -> dict | None:
    """What a map set's subsurface texels render with.

    Args:
        folder: the map set (for error messages).
        info: its maps.json document.
        maps: its ``relight.MaterialMaps``.

    Returns:
        None when no texel is on the subsurface rung; else the number of subsurface ``samples``, their
        median mean free path ``mfp_median_mm`` (R, G, B), ``eta`` (maps.json
        ``metadata.subsurface.eta``, else ``skin_bssrdf.SKIN_ETA``) and ``eta_from``.
    """
    on = np.asarray(maps.model) == SUBSURFACE
    if not on.any():
        return None
    recorded = ((info.get("metadata", {}) or {}).get("subsurface") or {}).get("eta")
    where = Path(folder) / "maps.json"
    try:
        eta = skin_bssrdf.SKIN_ETA if recorded is None else float(recorded)
    except (TypeError, ValueError):
        raise ValueError(f"{where}: metadata.subsurface.eta must be a number, got {recorded!r}") from None
    if not (np.isfinite(eta) and 1.0 < eta <= 3.0):
        raise ValueError(f"{where}: metadata.subsurface.eta must be in (1, 3], got {eta!r}")
    mfp = np.median(np.asarray(maps.mfp, np.float64)[on], axis=0)
    return {"samples": int(on.sum()), "eta": eta, "eta_from": "maps.json" if recorded is not None else "default",
            "mfp_median_mm": mfp.tolist()}


def render_cameras(camera, mesh: stage.Mesh, image_size: int | None = None, default=None) -> tuple:
    """The render cameras.

    Args:
        camera: "front" (``stage.front_camera``), a cameras file (``stage.load_cameras``; a folder: its
            cameras.json), a sequence of ``stage.Camera``, or None: ``default`` if given, else front.
        mesh: the subject (for the front camera).
        image_size: pixels of the front camera (N x N; default ``FRONT_SIZE``); other cameras are
            scaled to it on their longer side (:func:`relight.render.scaled_camera`).
        default: the input's own cameras.

    Returns:
        A tuple of ``stage.Camera``.
    """
    if camera is None:
        camera = tuple(default) if default else "front"
    if isinstance(camera, (str, os.PathLike)) and str(camera) == "front":
        return (stage.front_camera(mesh, FRONT_SIZE if image_size is None else image_size),)
    if isinstance(camera, (str, os.PathLike)):
        p = Path(camera)
        if p.is_dir():
            p = p / "cameras.json"
        if not p.is_file():
            raise FileNotFoundError(f"--camera {camera}: not 'front' and no such cameras file")
        cams = tuple(stage.load_cameras(p))
    else:
        cams = tuple(camera)
    if image_size is not None:
        cams = tuple(scaled_camera(c, image_size) for c in cams)
    return cams


def unseen_warnings(kind: str, unseen: list, n_cameras: int, pixels: list | None = None,
                    filled: bool = False) -> list[str]:
    """A warning per camera where at least ``UNSEEN_WARN`` of the subject's pixels lie on texels without data.

    Args:
        kind: the input kind (:func:`input_kind`).
        unseen: per camera, the fraction of the subject's pixels on texels without data (None: not known).
        n_cameras: the render cameras.
        pixels: per camera, ``(gaps, subject)`` pixel counts (:func:`relight.render.uncovered_pixels`), or None.
        filled: the map set fills the texels no camera saw (``relight.io.TextureSet.filled``): those pixels
            show the fill; otherwise they are black (a capture camera never saw them, or the map set holds no
            fitted sample there).

    Returns:
        The warnings, one line each.
    """
    if kind == "capture":
        why, shown = "no capture camera saw", "they are black in relit.exr (no data there)"
    elif filled:
        why = "no capture camera saw"
        shown = ("they show the map set's fill (the nearest seen texel's material, maps.json 'unseen'), not a "
                 "measurement: capture views that see those regions, or render from a camera closer to the "
                 "capture's")
    else:
        why, shown = "the map set holds no fitted sample on", "they are black in relit.exr (no data there)"
    out = []
    for k, u in enumerate(unseen):
        if u is not None and u >= UNSEEN_WARN:
            cam = "" if n_cameras == 1 else f" (camera {k})"
            count = "" if pixels is None else f" ({pixels[k][0]} of {pixels[k][1]})"
            out.append(f"warning{cam}: {100 * u:.1f}% of the subject's pixels{count} lie on texels {why}; {shown}")
    return out


def _channels(C: int) -> list[str]:
    """EXR channel names of a relit image with C colour channels and its coverage A."""
    return {1: ["Y", "A"], 3: ["R", "G", "B", "A"]}.get(C, [*(f"C{c}" for c in range(C)), "A"])


def _write_exr(path: Path, image: np.ndarray, **kw) -> None:
    from ..io import (
        check_finite_output,
        write_exr,  # looked up at each call: a test may replace relight.io.write_exr (a full disk)
    )
    from ..results import writing

    check_finite_output(image, path, "the relit image")
    with writing(path):
        write_exr(path, image, **kw)


def _write_preview(path: Path, rgb: np.ndarray, cov: np.ndarray, exposure: float, alpha: bool) -> None:
    """A PNG preview: ``rgb`` tone-mapped at ``exposure``; with ``alpha``, RGBA, the colour
    unpremultiplied (PNG's alpha is straight) and A the coverage."""
    from ..image import to_uint8, tonemap
    from ..io import write_png
    from ..results import writing

    # rgb is the frame _write_exr has just written and checked (check_finite_output): nothing to check again.
    if not alpha:
        from ..io import write_preview

        write_preview(path, rgb, exposure=exposure)
        return
    straight = np.where(cov[..., None] > 0, rgb / np.maximum(cov[..., None], 1e-6), 0.0).astype(np.float32)
    if straight.shape[-1] != 3:
        straight = np.repeat(straight.mean(-1, keepdims=True), 3, -1)
    rgba = np.concatenate([to_uint8(tonemap(straight, exposure=exposure, curve="filmic")), to_uint8(cov[..., None])],
                          axis=-1)
    with writing(path):
        write_png(path, rgba)


def _capture_views(src: Path, env: EnvMap, angles, camera, image_size, progress):
    """Image-based: the capture's texel radiance relit and seen through every camera."""
    from ..io import load_texel_capture

    capture, surface, mesh, _ = load_texel_capture(src, progress=progress)
    cameras = render_cameras(camera, mesh, image_size, capture.cameras[:1])
    seen, held = seen_texels(capture, surface)
    views = []
    bar = stage.Phase(progress, "render (frames)", len(angles) * len(cameras))
    for cam in cameras:
        frames = image_based_view(capture, surface, mesh, cam, env, rotations=y_rotations(angles))
        cov = pixel_coverage(mesh, cam)
        views.append((list(frames), cov, uncovered_pixels(cov, texel_fraction(mesh, cam, seen, valid=held))))
        bar.advance(len(angles))
    source = {"capture": capture, "surface": surface, "mesh": mesh}
    return views, cameras, "rig (the capture's own OLAT images)", None, mesh, source


def _map_set_views(src: Path, env: EnvMap, angles, method: AbstractMethod, rig_description, camera, image_size,
                   progress):
    """Model-based: the map set rendered by ``method`` through every camera."""
    from ..io import load_texel_maps

    tm = load_texel_maps(src)
    cameras = render_cameras(camera, tm.mesh, image_size, tm.cameras[:1] or None)
    info, coverage, filled = tm.textures.info, tm.textures.coverage, tm.textures.filled
    # The texture set's maps on the texel grid are not read again (the maps at the samples are, and the renderer
    # builds its own dilated textures from them): only the set's masks and record are kept (~80 B a texel less).
    maps, surface, mesh = tm.maps, tm.surface, tm.mesh
    del tm
    stage.release_freed_memory()
    subsurface = subsurface_settings(src, info, maps)
    settings = {} if subsurface is None else {"eta": subsurface["eta"]}
    desc = None
    if isinstance(method, Rig):
        if method.rig is None:
            rig, desc = map_set_rig(src, info)
            method = dataclasses.replace(method, rig=rig)
        else:
            desc = rig_description
    views = []
    bar = stage.Phase(progress, "render (frames)", len(angles) * len(cameras))
    for cam in cameras:
        frames = []
        for a in angles:
            rot = None if a % 360.0 == 0.0 else y_rotations([a])[0]
            img = render_view(maps, surface, mesh, cam, env, method=method, background=False,
                              progress=progress, rotation=rot, **settings)
            frames.append(np.asarray(img, np.float32))
            bar.advance(1)
        cov = pixel_coverage(mesh, cam)
        # Texels with data: those a camera saw (coverage); filled ones (no camera saw them) hold the set's fill,
        # so they count as gaps, not as gutter to pad from their neighbours.
        on = texel_fraction(mesh, cam, coverage, valid=coverage | filled)
        views.append((frames, cov, uncovered_pixels(cov, on)))
    label = method.name + ("" if desc is None else f" ({desc})")
    source = {"maps": maps, "surface": surface, "mesh": mesh, "method": method, "folder": src, **settings,
              "filled": bool(filled.any())}
    return views, cameras, label, subsurface, mesh, source


def render_folder(src: str | os.PathLike, envmap: str | os.PathLike | None, out: str | os.PathLike, *,
                  angles_deg=(0.0,), method: AbstractMethod | None = None, rig_description: str | None = None,
                  camera=None, image_size: int | None = None, background: str = "black",
                  exposure: float | None = None, rig_units: str | None = None, rig_up: str | None = None,
                  progress: stage.Progress | None = None) -> RenderedFolder:
    """Relight an input folder under an environment map and write the frames into ``out``.

    Args:
        src: a texel-space capture folder (relit image-based: a weighted sum of its one-light images), a
            photo capture (the same, each camera's own view, no geometry) or a fitted map set (rendered
            model-based by ``method``); see :func:`input_kind`.
        envmap: the environment map file (None: ``relight.envmap.bundled_envmap_path()``).
        out: an existing folder the outputs are written into.
        angles_deg: [K] rotations of the environment about +y (degrees): K frames.
        method: a method Module for a map set (default ``Rig()``: the rig the set records,
            :func:`map_set_rig`); a capture takes ``Rig()`` only (its own OLAT images).
        rig_description: what ``method``'s own rig is, for the records.
        camera: the render cameras (:func:`render_cameras`; default the input's own first camera).
        image_size: the render cameras' size (:func:`render_cameras`).
        background: one of ``BACKGROUNDS``.
        exposure: the previews' exposure in stops (None: ``relight.image.subject_exposure`` of every
            frame and camera, metered on the subject).
        rig_units, rig_up: a photo capture's rig file units and up axis (``relight.io.read_photo_capture``).
        progress: ``stage.Progress`` callback.

    Returns:
        A :class:`RenderedFolder`; ValueError when a frame has NaN or Inf pixels (nothing is written).

    References:
        Debevec et al. 2000, "Acquiring the Reflectance Field of a Human Face", sec. 4 (image-based).
    """
    from ..envmap import bundled_envmap_path, load_envmap
    from ..image import subject_exposure

    src, out = Path(src), Path(out)
    kind = input_kind(src)
    if background not in BACKGROUNDS:
        raise ValueError(f"background must be one of {BACKGROUNDS}, got {background!r}")
    envmap = Path(envmap) if envmap else bundled_envmap_path()
    env = load_envmap(envmap)
    angles = np.asarray(angles_deg, np.float64).reshape(-1)
    if not np.all(np.isfinite(angles)):
        raise ValueError(f"angles_deg must be finite, got {angles.tolist()}")
    method = Rig() if method is None else method
    if kind == "photos":
        return _render_photos(src, env, envmap, out, angles, background, exposure, rig_units, rig_up, progress)
    t0 = time.perf_counter()
    if kind == "capture":
        if not (isinstance(method, Rig) and method.rig is None):
            raise ValueError(f"{src}: a capture is relit image-based with its own rig; method {method!r} applies "
                             "to map sets")
        views, cameras, label, subsurface, mesh, source = _capture_views(src, env, angles, camera, image_size,
                                                                         progress)
    else:
        views, cameras, label, subsurface, mesh, source = _map_set_views(src, env, angles, method, rig_description,
                                                                         camera, image_size, progress)
    seconds = time.perf_counter() - t0
    # A non-finite frame is refused as it is written (_write_exr, _write_preview: check_finite_output); the
    # set is committed whole or not at all, so nothing of it is left.
    # One exposure for every frame and camera, so they compare; metered on the subject, not the background.
    given = exposure
    if exposure is None:
        C = views[0][0][0].shape[-1]
        exposure = subject_exposure(np.concatenate([f.reshape(-1, C) for fr, _, _ in views for f in fr])[None],
                                    np.concatenate([np.broadcast_to(cov, f.shape[:-1]).reshape(-1)
                                                    for fr, cov, _ in views for f in fr])[None])
    exposure = float(exposure)
    names = ["relit"] if len(angles) == 1 else [f"relit_{k:03d}" for k in range(len(angles))]
    folders = [""] if len(cameras) == 1 else [f"cam{k:03d}/" for k in range(len(cameras))]
    outputs = [f"{d}{n}.exr" for d in folders for n in names]
    pixels = [[int(g), int(n)] for _, _, (g, n) in views]
    unseen = [g / n if n else 0.0 for g, n in pixels]
    cam_docs = [stage.camera_to_dict(c) for c in cameras]
    for folder, cam, doc, (frames, cov, _) in zip(folders, cameras, cam_docs, views, strict=True):
        if folder:
            (out / folder).mkdir(exist_ok=True)
        for name, angle, img in zip(names, angles, frames, strict=True):
            rgb = img
            if background == "env":
                rot = None if angle % 360.0 == 0.0 else y_rotations([angle])[0]
                rgb = img + environment_behind(env, mesh, cam, rotation=rot)
            header = {"relight:command": "relight render", "relight:input": str(src),
                      "relight:input_kind": kind, "relight:envmap": str(envmap),
                      "relight:rotation_deg": float(angle), "relight:camera": doc, "relight:method": label,
                      "relight:background": background, "relight:preview_exposure_stops": exposure,
                      "relight:alpha": "coverage: fraction of the pixel the subject covers; RGB premultiplied"}
            _write_exr(out / f"{folder}{name}.exr", np.concatenate([rgb, cov[..., None]], axis=-1).astype(np.float32),
                       channels=_channels(rgb.shape[-1]), header=header)
            _write_preview(out / f"{folder}{name}.png", rgb, cov, exposure, background == "alpha")
    resolved = dict(input_kind=kind, envmap=str(envmap), method=label, rotations_deg=angles.tolist(),
                    camera=cam_docs[0] if len(cameras) == 1 else None, cameras=cam_docs,
                    camera_folders=None if len(cameras) == 1 else [d[:-1] for d in folders],
                    image_size=[[c.width, c.height] for c in cameras], background=background,
                    preview_exposure_stops=exposure,
                    exposure_from="--exposure" if given is not None else "subject median luminance",
                    unseen_pixel_fraction=unseen, unseen_pixels=pixels, unseen_warn=UNSEEN_WARN,
                    seconds=round(seconds, 3), subsurface=subsurface, outputs=outputs)
    tail = "" if subsurface is None else (f", subsurface on {subsurface['samples']} texels "
                                          f"(eta {subsurface['eta']:g})")
    cams = "" if len(cameras) == 1 else f" x {len(cameras)} cameras"
    summary = f"({len(angles)} frame(s){cams}, {kind}, method {label}{tail})"
    return RenderedFolder(kind, resolved, outputs, [out / f"{folders[0]}{n}.png" for n in names], angles, exposure,
                          tuple(cameras), unseen_warnings(kind, unseen, len(cameras), pixels,
                                                          source.get("filled", False)), summary, source)


def _render_photos(src: Path, env: EnvMap, envmap: Path, out: Path, angles, background: str, exposure, rig_units,
                   rig_up, progress) -> RenderedFolder:
    """Image-based relighting of a photo capture, camera by camera (:func:`relight_photographs`): per
    camera ``<camera>/relit.exr`` (R, G, B, A: A is the lighting coverage) + ``relit.png``, or
    ``relit_000.exr`` ... for a turntable."""
    from ..image import subject_exposure
    from ..io import read_photo_capture

    if background == "env":
        raise ValueError("background 'env': a photo capture has no geometry to tell the subject from the "
                         "background by; relit.exr's A (the lighting coverage) is 0 outside its masks")
    t0 = time.perf_counter()
    capture = read_photo_capture(src, rig_units=rig_units, rig_up=rig_up)
    rig = capture.rig
    weights = image_based_weights(env, rig, y_rotations(angles))  # [K, L, C]
    names = ["relit"] if len(angles) == 1 else [f"relit_{k:03d}" for k in range(len(angles))]
    outputs, previews = [], []
    bar = stage.Phase(progress, "relight (cameras)", capture.n_views)
    for v, view in enumerate(capture.iter_views()):
        try:
            frames, cover = relight_photographs(view.radiance, view.mask, weights, view.valid)
        except ValueError as err:
            raise ValueError(f"{capture.files(v)[0]}: {err}") from None  # names the camera's first file
        if exposure is None:  # the first camera's subject exposure for every camera and frame, so all compare
            H, W = view.mask.shape
            exposure = subject_exposure(frames, view.mask.reshape(1, H, W).astype(np.float32))
        (out / view.name).mkdir(exist_ok=True)
        channels = _channels(frames.shape[-1])
        for name, img, cov in zip(names, frames, cover, strict=True):
            _write_exr(out / view.name / f"{name}.exr", np.concatenate([img, cov], axis=-1), channels=channels)
            _write_preview(out / view.name / f"{name}.png", img, cov[..., 0], exposure, background == "alpha")
            outputs.append(f"{view.name}/{name}.exr")
            if v == 0:
                previews.append(out / view.name / f"{name}.png")
        bar.advance(1)
    seconds = time.perf_counter() - t0
    label = "rig (the photographs' own rig, image-based, per camera)"
    resolved = dict(input_kind="photos", envmap=str(envmap), method=label, rig_file=str(capture.rig_file),
                    lights=rig.num_lights, cameras=list(capture.names), rotations_deg=angles.tolist(),
                    preview_exposure_stops=exposure, seconds=round(seconds, 3), outputs=outputs)
    summary = f"({capture.n_views} camera(s) x {len(angles)} frame(s), photo capture, method rig)"
    return RenderedFolder("photos", resolved, outputs, previews, angles, float(exposure), tuple(capture.names), [],
                          summary, {"photos": capture})
