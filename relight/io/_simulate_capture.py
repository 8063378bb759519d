"""Simulated captures written whole: a texel-space capture folder or store with its ground truth, or a
camera-space photo capture, of the demo's skin-like material on a mesh (what ``relight simulate`` writes)."""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

import brdf
import skin_bssrdf
import stage

from ..image import dilate, texture_view
from ..materials import GGX, SUBSURFACE, demo_material, material_maps
from ..results import open_result_set
from ._capture_writer import CaptureFolderWriter, store_blocks
from ._exr import write_exr
from ._mean_free_path import mean_free_path_at
from ._photos import write_photo_capture
from ._previews import write_map_previews, write_preview
from ._store import LIGHT_CHUNK, CaptureStoreWriter
from ._texture_set import write_maps

__all__ = ["MeanFreePath", "SimulatedCapture", "peak_rss_mib", "release_freed_memory", "simulate_photo_capture",
           "simulate_texel_capture"]

# Lights per stage.simulate_into chunk: a store two store chunks' worth (LIGHT_CHUNK lights each; with
# subsurface one), so every write completes its store chunks; a folder stage.simulate's default.
STORE_LIGHT_CHUNK, SUBSURFACE_STORE_LIGHT_CHUNK, FOLDER_LIGHT_CHUNK = 2 * LIGHT_CHUNK, LIGHT_CHUNK, 64
# Texels per call of the camera visibility pass (stage.camera_visibility's chunk).
CAMERA_CHUNK = 1 << 16
_MATERIAL = "relight demo skin (Lambert + GGX, F0 0.028, alpha 0.2-0.5)"
_SSS_MATERIAL = ("relight demo skin (GGX, F0 0.028, alpha 0.2-0.5, + subsurface scattering: Burley profile of "
                 "albedo rho_d and the mean free path of metadata.subsurface)")
_UNITS = {"lengths": "mm", "radiance": "relative to the rig's irradiance"}


@dataclasses.dataclass(frozen=True)
class MeanFreePath:
    """The subsurface scattering of a simulated capture: the diffuse mean free path and the Fresnel eta.

    Fields:
        mfp: float [3] (mm per channel, everywhere) or [H, W, 3] (a map on the texture atlas; 0 = no
            subsurface at that texel), as ``relight.io.read_mean_free_path`` gives it.
        eta: the relative index of refraction of the Fresnel transmittances.
        source: what the mean free path is (recorded: "preset skin1", a file name).
        scale: the factor already applied to ``mfp`` (recorded).
    """

    mfp: np.ndarray
    eta: float = skin_bssrdf.SKIN_ETA
    source: str = ""
    scale: float = 1.0


@dataclasses.dataclass(frozen=True)
class SimulatedCapture:
    """What :func:`simulate_texel_capture` / :func:`simulate_photo_capture` wrote.

    Fields:
        path: the capture folder or store.
        resolved: the settings to record (views, lights, samples seen, timings, peak memory, ...).
        summary: one line saying what was written.
        images, masks: the photo capture's images [L, H, W, C] and masks [H, W] per camera (photo
            captures only; None otherwise).
    """

    path: Path
    resolved: dict
    summary: str
    images: list | None = None
    masks: list | None = None


def peak_rss_mib() -> float | None:
    """The process's peak resident set so far.

    Returns:
        MiB (Linux's ``ru_maxrss`` is in KiB), or None where the platform does not say.
    """
    try:
        import resource

        return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
    except (ImportError, OSError):  # pragma: no cover - not Linux / macOS
        return None


def release_freed_memory() -> None:
    """Hand freed heap back to the system (glibc's ``malloc_trim``; nothing elsewhere).

    A texel grid's temporaries (``stage.texel_samples``, the camera visibility of the whole grid: hundreds
    of bytes a texel) are freed but kept by glibc; trimming stops them staying resident under the phases
    that follow.
    """
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # pragma: no cover - not glibc
        pass


def _mark() -> float | None:
    peak = peak_rss_mib()
    release_freed_memory()
    return peak


def _noise(sensor, seed: int, sample: str) -> dict | None:
    return None if sensor is None else {
        "model": "poisson-gaussian", "exposure": float(sensor.exposure), "read_noise": float(sensor.read_noise),
        "seed": int(seed), "keys": f"fold_in(fold_in(fold_in(PRNGKey(seed), view), light), {sample})"}


def _truth(surface, subsurface: MeanFreePath | None, progress):
    """The demo material on the seen samples: (maps, truth brdf, stage.Subsurface or None, subsurface record)."""
    rho, f0, alpha = demo_material(surface)
    truth = brdf.lambert_ggx(rho, f0, alpha)
    if subsurface is None:
        return material_maps(surface, rho, f0, alpha), truth, None, None
    stage.Phase(progress, "subsurface operator", None)
    mfp = mean_free_path_at(subsurface.mfp, surface)
    if not np.any(mfp > 0):
        raise ValueError("mean_free_path: the mean free path is 0 at every texel the camera sees (no subsurface "
                         "scattering)")
    sss = stage.subsurface_from_maps(surface, rho, mfp, subsurface.eta)
    on = np.any(mfp > 0, axis=1)
    # Subsurface texels take their diffuse light from the operator; the others keep the local Lambert term.
    truth = brdf.Sum(brdf.Lambert(np.asarray(rho) * (~on)[:, None]), stage.split_material(truth)[1])
    model = np.where(on, SUBSURFACE, GGX).astype(np.int32)
    record = {"source": subsurface.source, "mfp_scale": subsurface.scale, "eta": subsurface.eta,
              "mfp_mm": (np.asarray(subsurface.mfp).tolist() if np.ndim(subsurface.mfp) == 1
                         else np.median(mfp[on], axis=0).tolist()),  # a map: the median over subsurface texels
              "subsurface_samples": int(on.sum()),
              "profile": "Burley dmfp (Christensen & Burley 2015), albedo = the diffuse albedo rho_d",
              "operator": {"radius_mm": round(float(sss.operator.radius), 4),
                           "energy_fraction": skin_bssrdf.OPERATOR_ENERGY,
                           "max_neighbours": int(sss.operator.index.shape[1])}}
    return material_maps(surface, rho, f0, alpha, mfp=mfp, model=model), truth, sss, record


def _write_truth(out: Path, mesh, camera, surface, all_on, maps, surface_info, record) -> None:
    """truth/ (the ground-truth map set, with its previews) and the preview (view 0 with every light on:
    ``all_on`` [H*W, C] on the texel grid) into ``out``."""
    H, W = surface.resolution
    meta = {"source": "relight simulate ground truth"}
    if record is not None:
        meta["subsurface"] = {"eta": record["eta"], "source": record["source"]}
    covered = np.zeros((H, W), bool)
    covered.reshape(-1)[np.asarray(surface.texel_index)] = True
    write_maps(out / "truth", maps, surface, surface_info=surface_info, metadata=meta)
    # truth/'s previews, as a fit writes its own, added to truth/'s manifest (truth/ is inside the capture being
    # built at `out`: no reader sees it before the whole capture is in place).
    grid = lambda x: dilate(surface.to_texture(np.asarray(x, np.float32)), covered)  # noqa: E731
    write_map_previews(out / "truth", grid(maps.rho_d), grid(maps.rho_s), grid(np.asarray(maps.alpha)[:, :1]))
    open_result_set(out / "truth").add("albedo.png", "specular.png", "roughness.png")
    view = texture_view(mesh, camera, {"all_lights": dilate(all_on.reshape(H, W, -1), covered)})["all_lights"]
    write_exr(out / "preview_all_lights.exr", view)
    write_preview(out / "preview_all_lights.png", view)


def simulate_texel_capture(out: str | os.PathLike, mesh: stage.Mesh, resolution, rig: stage.Rig, cameras,
                           *, surface_info: Mapping, rig_info=None, store: bool = False,
                           block: int = stage.DEFAULT_BLOCK, half: bool = False, sensor: stage.Sensor | None = None,
                           seed: int = 0, subsurface: MeanFreePath | None = None, metadata: Mapping | None = None,
                           progress: stage.Progress | None = None) -> SimulatedCapture:
    """Simulate an OLAT capture of the demo's skin-like material on a texel grid and write it with its truth.

    The mesh's texel grid (``stage.texel_samples``) and the cameras' visibility of it
    (``stage.camera_visibility``, ``CAMERA_CHUNK`` texels at a time) pick the seen texels; the demo material
    (``relight.materials.demo_material``) over them, with ``subsurface`` its local Lambert term replaced by
    subsurface scattering where the mean free path is > 0 (``stage.subsurface_from_maps``); then
    ``stage.simulate_into`` a capture folder (:class:`CaptureFolderWriter`, held in memory) or a capture store
    (:class:`CaptureStoreWriter`, streamed block by block; with subsurface one block), the full grid
    [V, L, H*W, C] with unseen texels 0 and invalid; truth/ (the ground-truth map set and its previews) and
    preview_all_lights.exr/.png inside.

    Args:
        out: the capture folder or store to write (created; a store replaces one there).
        mesh: the mesh, with UVs.
        resolution: the texel grid, N (N x N) or (H, W).
        rig: the lights.
        cameras: the V cameras.
        surface_info: how to rebuild the surface (``relight.io.mesh_spec``); the resolution is added.
        rig_info: the rig's description, recorded in the metadata.
        store: a capture store (else a capture folder).
        block: grid texels per block of a store, rounded down to whole store chunks (:func:`store_blocks`).
        half: radiance as half floats.
        sensor: optional ``stage.Sensor``; its noise follows ``stage.observation_key``.
        seed: the noise seed.
        subsurface: optional :class:`MeanFreePath`.
        metadata: entries that replace the capture metadata's own (``noise``, ``writer``, ...).
        progress: ``stage.Progress`` for every phase.

    Returns:
        A :class:`SimulatedCapture`.

    Raises:
        ValueError: "cameras: ..." when no texel is seen, "mean_free_path: ..." when the mean free path is 0
            at every seen texel.

    References:
        Jensen et al. 2001, "A Practical Model for Subsurface Light Transport", eq. 5 (the subsurface term);
        Christensen & Burley 2015 (the profile).
    """
    out = Path(out)
    cameras = tuple(cameras)
    t0 = time.perf_counter()
    grid = stage.texel_samples(mesh, resolution)
    times, memory = {"geometry_s": time.perf_counter() - t0}, {"geometry": _mark()}
    t0 = time.perf_counter()
    cam_vis = stage.camera_visibility(mesh, grid, cameras, chunk=CAMERA_CHUNK)
    seen = np.nonzero(np.any(cam_vis, axis=0))[0]
    if len(seen) == 0:
        raise ValueError("cameras: no texel of the mesh is seen by any camera")
    surface, cam_vis = grid.subset(seen), cam_vis[:, seen]
    times["camera_visibility_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    maps, truth, sss, record = _truth(surface, subsurface, progress)
    if sss is not None:
        times["subsurface_operator_s"] = time.perf_counter() - t0
    (H, W), V, L, C = grid.resolution, len(cameras), rig.num_lights, 3
    del grid  # only the seen texels from here (the grid's surface is ~70 B a texel)
    memory["camera_visibility"] = _mark()
    dtype = np.float16 if half else np.float32
    info = {**surface_info, "resolution": [H, W]}
    meta = {"space": "texel", "surface": info, "rig": rig_info,
            "material": f"{_MATERIAL if sss is None else _SSS_MATERIAL}, ground truth in truth/",
            "subsurface": record, "noise": _noise(sensor, seed, "texel"), "units": _UNITS,
            "writer": "relight.io.simulate_texel_capture", **(metadata or {})}
    if store:
        block, pc = store_blocks(H * W, block, C, dtype)
        writer = CaptureStoreWriter(out, (V, L, H * W, C), dtype, rig, cameras, meta, (1, LIGHT_CHUNK, pc, C),
                                    sample_shape=(H, W))
        lc = STORE_LIGHT_CHUNK if sss is None else SUBSURFACE_STORE_LIGHT_CHUNK
    else:
        block, lc = H * W, FOLDER_LIGHT_CHUNK
        writer = CaptureFolderWriter(out, (V, L, H * W, C), dtype, rig, cameras, meta, sample_shape=(H, W))
    t0 = time.perf_counter()
    with writer:
        done = stage.simulate_into(writer, mesh, surface, rig, cameras, truth, cam_vis, subsurface=sss,
                                   sensor=sensor, seed=seed, block=block, light_chunk=lc, progress=progress)
    times["visibility_s"], times["simulate_s"] = done.visibility_s, time.perf_counter() - t0 - done.visibility_s
    memory["simulate"] = _mark()
    t0 = time.perf_counter()
    _write_truth(out, mesh, cameras[0], surface, done.all_lights, maps, surface_info, record)
    times["write_s"], memory["write"] = time.perf_counter() - t0, _mark()
    form = {"form": "store", "block_texels": done.block, "store_chunks": [1, LIGHT_CHUNK, int(pc), C],
            "blocks": done.blocks} if store else {}
    resolved = {"mesh": info, "rig": rig_info, "lights": L, "views": V, "samples_seen": int(len(seen)),
                "texels": [H, W], "subsurface": record, **form,
                "timings_s": {k: round(v, 3) for k, v in times.items()}, "peak_rss_mib": memory}
    tail = "" if record is None else (f", subsurface {record['source']}: mfp "
                                      + "/".join(f"{x:.3g}" for x in record["mfp_mm"]) + " mm (R/G/B)")
    blocks = f", {done.blocks} blocks of {done.block} texels" if store else ""
    summary = (f"({'capture store: ' if store else ''}{V} view(s) x {L} lights, {len(seen)} of {H}x{W} texels "
               f"seen{tail}{blocks})")
    return SimulatedCapture(out, resolved, summary)


def simulate_photo_capture(out: str | os.PathLike, mesh: stage.Mesh, rig: stage.Rig, cameras, *,
                           mesh_info: Mapping, rig_info=None, half: bool = False, sensor: stage.Sensor | None = None,
                           seed: int = 0, metadata: Mapping | None = None,
                           progress: stage.Progress | None = None) -> SimulatedCapture:
    """Simulate the photographs of an OLAT capture of the demo's material and write them as a photo capture.

    ``stage.simulate_images`` (per camera: one sample per pixel, visibility, the OLAT radiance, the sensor
    keyed by ``stage.observation_key`` with the pixel as the sample) written by :func:`write_photo_capture`
    with each camera's mask (the pixels that see the mesh), and preview_all_lights.exr/.png (camera 0 with
    every light on).

    Args:
        out: the photo capture folder to write.
        mesh: the mesh.
        rig: the lights.
        cameras: the cameras.
        mesh_info: the mesh's description, recorded (``relight.io.mesh_spec``).
        rig_info: the rig's description, recorded.
        half: radiance as half floats.
        sensor: optional ``stage.Sensor``.
        seed: the noise seed.
        metadata: entries that replace the capture metadata's own.
        progress: ``stage.Progress``.

    Returns:
        A :class:`SimulatedCapture` with the images and masks.

    Raises:
        ValueError: "camera N: ..." when a camera sees no part of the mesh.
    """
    out = Path(out)
    cameras = tuple(cameras)
    t0 = time.perf_counter()
    images, masks = stage.simulate_images(mesh, rig, cameras, lambda s: brdf.lambert_ggx(*demo_material(s)),
                                          sensor=sensor, seed=seed, progress=progress)
    times = {"simulate_s": time.perf_counter() - t0}
    meta = {"space": "image", "mesh": dict(mesh_info), "rig": rig_info, "noise": _noise(sensor, seed, "pixel"),
            "material": _MATERIAL, "units": _UNITS, "writer": "relight.io.simulate_photo_capture", **(metadata or {})}
    t0 = time.perf_counter()
    write_photo_capture(out, images, rig, cameras, half=half, masks=masks, metadata=meta)
    all_on = images[0].sum(axis=0)
    write_exr(out / "preview_all_lights.exr", all_on)
    write_preview(out / "preview_all_lights.png", all_on)
    times["write_s"] = time.perf_counter() - t0
    resolved = {"mesh": dict(mesh_info), "rig": rig_info, "lights": rig.num_lights, "views": len(cameras),
                "pixels_seen": [int(m.sum()) for m in masks], "timings_s": {k: round(v, 3) for k, v in times.items()}}
    return SimulatedCapture(out, resolved, f"({len(cameras)} camera(s) x {rig.num_lights} lights, photo capture)",
                            images, masks)
