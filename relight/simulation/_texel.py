"""A simulated texel-space capture of the demo's skin-like material on a mesh, written whole: a capture folder
or a capture store with its ground truth (what ``relight simulate`` writes in texel space)."""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

import brdf
import skin_bssrdf
import stage

from ..image import dilate, texture_view
from ..io import (
    LIGHT_CHUNK,
    CaptureFolderWriter,
    CaptureStoreWriter,
    check_finite_output,
    mean_free_path_at,
    store_blocks,
    write_exr,
    write_map_previews,
    write_maps,
    write_preview,
)
from ..materials import GGX, SUBSURFACE, demo_material, material_maps
from ..results import open_result_set
from ._capture import MATERIAL, SSS_MATERIAL, UNITS, MeanFreePath, SimulatedCapture, noise_record

__all__ = ["simulate_texel_capture"]

# Lights per stage.simulate_into chunk: a store two store chunks' worth (LIGHT_CHUNK lights each; with
# subsurface one), so every write completes its store chunks; a folder stage.simulate's default.
STORE_LIGHT_CHUNK, SUBSURFACE_STORE_LIGHT_CHUNK, FOLDER_LIGHT_CHUNK = 2 * LIGHT_CHUNK, LIGHT_CHUNK, 64
# Texels per call of the camera visibility pass (stage.camera_visibility's chunk).
CAMERA_CHUNK = 1 << 16


def _mark() -> float | None:
    """The peak resident set so far (MiB, ``stage.peak_rss_mib``), then ``stage.release_freed_memory``."""
    peak = stage.peak_rss_mib()
    stage.release_freed_memory()
    return peak


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
    check_finite_output(view, out / "preview_all_lights.exr", "the all-lights preview")
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
    ``stage.simulate_into`` a capture folder (``relight.io.CaptureFolderWriter``, held in memory) or a capture store
    (``relight.io.CaptureStoreWriter``, streamed block by block; with subsurface one block), the full grid
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
        block: grid texels per block of a store, rounded down to whole store chunks (``relight.io.store_blocks``).
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
            "material": f"{MATERIAL if sss is None else SSS_MATERIAL}, ground truth in truth/",
            "subsurface": record, "noise": noise_record(sensor, seed, "texel"), "units": UNITS,
            "writer": "relight.simulation.simulate_texel_capture", **(metadata or {})}
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
