"""A simulated camera-space photo capture of the demo's material (``relight simulate --space image``)."""

from __future__ import annotations

import os
import time
from collections.abc import Mapping
from pathlib import Path

import brdf
import stage

from ..io import check_finite_output, write_exr, write_photo_capture, write_preview
from ..materials import demo_material
from ._capture import MATERIAL, UNITS, SimulatedCapture, noise_record

__all__ = ["simulate_photo_capture"]


def simulate_photo_capture(out: str | os.PathLike, mesh: stage.Mesh, rig: stage.Rig, cameras, *,
                           mesh_info: Mapping, rig_info=None, half: bool = False, sensor: stage.Sensor | None = None,
                           seed: int = 0, metadata: Mapping | None = None,
                           progress: stage.Progress | None = None) -> SimulatedCapture:
    """Simulate the photographs of an OLAT capture of the demo's material and write them as a photo capture.

    ``stage.simulate_images`` (per camera: one sample per pixel, visibility, the OLAT radiance, the sensor
    keyed by ``stage.observation_key`` with the pixel as the sample) written by ``relight.io.write_photo_capture``
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
    meta = {"space": "image", "mesh": dict(mesh_info), "rig": rig_info, "noise": noise_record(sensor, seed, "pixel"),
            "material": MATERIAL, "units": UNITS, "writer": "relight.simulation.simulate_photo_capture",
            **(metadata or {})}
    t0 = time.perf_counter()
    write_photo_capture(out, images, rig, cameras, half=half, masks=masks, metadata=meta)
    all_on = images[0].sum(axis=0)
    check_finite_output(all_on, out / "preview_all_lights.exr", "the all-lights preview")
    write_exr(out / "preview_all_lights.exr", all_on)
    write_preview(out / "preview_all_lights.png", all_on)
    times["write_s"] = time.perf_counter() - t0
    resolved = {"mesh": dict(mesh_info), "rig": rig_info, "lights": rig.num_lights, "views": len(cameras),
                "pixels_seen": [int(m.sum()) for m in masks], "timings_s": {k: round(v, 3) for k, v in times.items()}}
    return SimulatedCapture(out, resolved, f"({len(cameras)} camera(s) x {rig.num_lights} lights, photo capture)",
                            images, masks)
