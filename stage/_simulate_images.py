"""A camera-space OLAT capture: one image per camera and light, as a real stage delivers it."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

import brdf

from ._camera import Camera
from ._image import image_samples
from ._mesh import Mesh
from ._progress import Phase
from ._rig import Rig
from ._sensor import Sensor, sense_keyed
from ._simulate import simulate_chunks
from ._surface import Surface
from ._visibility import camera_visibility, light_visibility

# Lights per simulate chunk (and per sensor call): stage.simulate's default.
_LIGHT_CHUNK = 64


def simulate_images(mesh: Mesh, rig: Rig, cameras, material: brdf.AbstractBRDF | Callable[[Surface], brdf.AbstractBRDF],
                    *, sensor: Sensor | None = None, seed=0, progress=None) -> tuple[list, list]:
    """Simulate the photographs of an OLAT capture: per camera, one image per light.

    Per camera: one sample per pixel whose ray hits the mesh (``image_samples``),
    the light and camera visibility, the OLAT radiance (``simulate_chunks``) and
    the sensor (``sense_keyed``: pixel ``row * width + column`` is the sample
    index of the one seeding rule, the camera's index the view).

    Args:
        mesh: the mesh.
        rig: the L lights.
        cameras: one ``Camera`` or a sequence of V.
        material: a brdf Module with shared parameters, or a function of the
            camera's pixel samples (a ``Surface``) giving the material on them.
        sensor: optional ``Sensor``; None: noise-free radiance.
        seed: the noise seed (``observation_key``).
        progress: ``Progress``, phase "simulate", counting (camera, light) images.

    Returns:
        (images, masks): per camera, float32 [L, H, W, C] radiance (>= 0, 0 off the
        mesh and where the camera does not see it) and bool [H, W], the pixels that
        see the mesh.

    Raises:
        ValueError: naming the camera when it sees no part of the mesh.
    """
    cameras = (cameras,) if isinstance(cameras, Camera) else tuple(cameras)
    L = rig.num_lights
    bar = Phase(progress, "simulate", L * len(cameras))
    images, masks = [], []
    for v, cam in enumerate(cameras):
        try:
            surface = image_samples(mesh, cam)
        except ValueError as err:
            raise ValueError(f"camera {v}: {err}") from None
        light_vis = light_visibility(mesh, surface, rig, chunk=1 << 18)
        cam_vis = camera_visibility(mesh, surface, [cam])
        m = material if isinstance(material, brdf.AbstractBRDF) else material(surface)
        H, W = cam.height, cam.width
        idx = np.asarray(surface.texel_index)
        img = np.zeros((L, H * W, int(np.asarray(rig.intensity).shape[-1])), np.float32)
        for _, ls, _, rad, msk in simulate_chunks(surface, rig, [cam], m, light_vis, cam_vis,
                                                  light_chunk=_LIGHT_CHUNK, sample_chunk=surface.num_samples):
            r, _ = sense_keyed(sensor, seed, rad, msk, view=v, lights=ls.start, samples=idx)
            img[ls][:, idx] = r  # (img[ls, idx] would put the sample axis first)
            bar.advance(ls.stop - ls.start)
        seen = np.zeros(H * W, bool)
        seen[idx] = cam_vis[0]
        img[:, ~seen] = 0.0
        images.append(img.reshape(L, H, W, -1))
        masks.append(seen.reshape(H, W))
    return images, masks
