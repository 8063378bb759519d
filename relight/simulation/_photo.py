"""A simulated camera-space photo capture of the demo's material (``relight simulate --space image``)."""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

import brdf
import stage

from ..io import PhotoCaptureWriter, check_finite_output, write_exr, write_preview
from ..materials import demo_material
from ._capture import MATERIAL, UNITS, SimulatedCapture, noise_record

__all__ = ["simulate_photo_capture"]


def simulate_photo_capture(out: str | os.PathLike, mesh: stage.Mesh, rig: stage.Rig, cameras, *,
                           mesh_info: Mapping, rig_info=None, half: bool = False, sensor: stage.Sensor | None = None,
                           seed: int = 0, fmt: str = "exr", metadata: Mapping | None = None,
                           progress: stage.Progress | None = None) -> SimulatedCapture:
    """Simulate the photographs of an OLAT capture of the demo's material and write them as a photo capture.

    ``stage.iter_images`` (per camera: one sample per pixel, visibility, the OLAT radiance, the sensor keyed by
    ``stage.observation_key`` with the pixel as the sample), each light chunk written as it comes by
    ``relight.io.PhotoCaptureWriter`` (memory is one chunk, not the capture), with each camera's mask (the pixels
    that see the mesh), and preview_all_lights.exr/.png (camera 0 with every light on).

    ``fmt="png"`` writes what a camera delivers: 16-bit PNGs of the sensor's counts, value = counts / 65535 with
    counts = ``sensor.exposure / sensor.gain`` x radiance (a 16-bit converter: rounded, clipped at 65535), the
    file's ``gain`` (value per unit radiance) recorded in capture.json with ``saturation`` 1.0, so a clipped
    pixel is invalid under its light when read back. It needs a ``sensor`` (the counts are its).

    Args:
        out: the photo capture folder to write.
        mesh: the mesh.
        rig: the lights.
        cameras: the cameras.
        mesh_info: the mesh's description, recorded (``relight.io.mesh_spec``).
        rig_info: the rig's description, recorded.
        half: radiance as half floats (EXR).
        sensor: optional ``stage.Sensor``.
        seed: the noise seed.
        fmt: "exr" (float radiance) or "png" (16-bit counts; needs ``sensor``).
        metadata: entries that replace the capture metadata's own.
        progress: ``stage.Progress``.

    Returns:
        A :class:`SimulatedCapture` with the masks (``images`` None: read them back with
        ``relight.io.read_photo_capture``); ``resolved["clipped_fraction"]`` is the fraction of the seen pixels'
        values clipped at full scale (PNG; 0 for EXR).

    Raises:
        ValueError: "camera N: ..." when a camera sees no part of the mesh; "fmt: ..." on an unknown format or a
            PNG capture without a sensor.
    """
    out = Path(out)
    cameras = tuple(cameras)
    if fmt not in ("exr", "png"):
        raise ValueError(f"fmt: must be 'exr' or 'png', got {fmt!r}")
    if fmt == "png" and sensor is None:
        raise ValueError("fmt: a PNG photo capture holds a sensor's 16-bit counts: it needs a sensor")
    scale = 1.0 if fmt == "exr" else float(sensor.exposure) / (float(sensor.gain) * 65535.0)
    t0 = time.perf_counter()
    meta = {"space": "image", "mesh": dict(mesh_info), "rig": rig_info, "noise": noise_record(sensor, seed, "pixel"),
            "material": MATERIAL, "units": UNITS, "writer": "relight.simulation.simulate_photo_capture",
            **({"counts": f"16-bit, counts = 65535 x gain x radiance, gain {scale:.6g}"} if fmt == "png" else {}),
            **(metadata or {})}
    png = {"gain": [scale] * len(cameras), "saturation": 1.0} if fmt == "png" else {}
    masks, all_on, clipped, seen_values = [], None, 0, 0
    with PhotoCaptureWriter(out, rig, cameras, fmt=fmt, half=half, metadata=meta, **png) as writer:
        for view, lights, images, mask in stage.iter_images(
                mesh, rig, cameras, lambda s: brdf.lambert_ggx(*demo_material(s)), sensor=sensor, seed=seed,
                progress=progress):
            if lights.start == 0:
                masks.append(mask)
                writer.write_mask(view, mask)
            if view == 0:
                part = images.sum(axis=0)
                all_on = part if all_on is None else all_on + part
            if fmt == "png":
                clipped += int(np.count_nonzero(images[:, mask] * scale >= 1.0))
                seen_values += images[:, mask].size
            writer.write(view, lights, images * np.float32(scale) if fmt == "png" else images)
        check_finite_output(all_on, out / "preview_all_lights.exr", "the all-lights preview")
        write_exr(writer.tmp / "preview_all_lights.exr", all_on)
        write_preview(writer.tmp / "preview_all_lights.png", all_on)
    times = {"simulate_write_s": time.perf_counter() - t0}
    resolved = {"mesh": dict(mesh_info), "rig": rig_info, "lights": rig.num_lights, "views": len(cameras),
                "format": fmt, "pixels_seen": [int(m.sum()) for m in masks],
                "clipped_fraction": clipped / max(1, seen_values),
                "timings_s": {k: round(v, 3) for k, v in times.items()}}
    return SimulatedCapture(out, resolved, f"({len(cameras)} camera(s) x {rig.num_lights} lights, photo capture)",
                            None, masks)
