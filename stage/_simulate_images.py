"""A camera-space OLAT capture: one image per camera and light, as a real stage delivers it."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import NamedTuple

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
# Pixel-lights per chunk when iter_images picks its light chunk: the chunk's shading temporaries stay a few
# hundred MiB whatever the camera's size.
_CHUNK_PIXEL_LIGHTS = 1 << 22


class ImageChunk(NamedTuple):
    """One light chunk of one camera's photographs (what :func:`iter_images` yields).

    Fields:
        view: the camera's index.
        lights: the slice of the rig's lights these photographs are of.
        images: float32 [nL, H, W, C] radiance (>= 0, 0 off the mesh and where the camera does not see it).
        mask: bool [H, W], the pixels that see the mesh (the same for every chunk of a camera).
    """

    view: int
    lights: slice
    images: np.ndarray
    mask: np.ndarray


def iter_images(mesh: Mesh, rig: Rig, cameras,
                material: brdf.AbstractBRDF | Callable[[Surface], brdf.AbstractBRDF], *,
                sensor: Sensor | None = None, seed=0, light_chunk: int | None = None,
                progress=None) -> Iterator[ImageChunk]:
    """Simulate the photographs of an OLAT capture a light chunk at a time, camera after camera.

    Per camera: one sample per pixel whose ray hits the mesh (``image_samples``), the light visibility (packed, 8
    lights a byte) and camera visibility, the OLAT radiance (``simulate_chunks``) and the sensor (``sense_keyed``:
    pixel ``row * width + column`` is the sample index of the one seeding rule, the camera's index the view), so
    the noise of a photograph does not depend on the chunking. Peak memory is one chunk's photographs
    (``light_chunk`` x H x W x C floats) plus the shading of ``light_chunk`` lights over the camera's seen pixels,
    not the capture: a 2048^2 camera under 346 lights (17 GiB as float32) streams in a few hundred MiB.

    Args:
        mesh: the mesh.
        rig: the L lights.
        cameras: one ``Camera`` or a sequence of V.
        material: a brdf Module with shared parameters, or a function of the camera's pixel samples (a
            ``Surface``) giving the material on them.
        sensor: optional ``Sensor``; None: noise-free radiance.
        seed: the noise seed (``observation_key``).
        light_chunk: lights per chunk (>= 1); None: as many as keep a chunk near 2^22 pixel-lights (at most 64).
        progress: ``Progress``, phase "simulate", counting (camera, light) images.

    Yields:
        :class:`ImageChunk` s, cameras in order, each camera's lights in order.

    Raises:
        ValueError: naming the camera when it sees no part of the mesh; on a ``light_chunk`` < 1.
    """
    cameras = (cameras,) if isinstance(cameras, Camera) else tuple(cameras)
    if light_chunk is not None and int(light_chunk) < 1:
        raise ValueError(f"light_chunk must be >= 1, got {light_chunk}")
    L = rig.num_lights
    C = int(np.asarray(rig.intensity).shape[-1])
    bar = Phase(progress, "simulate", L * len(cameras))
    for v, cam in enumerate(cameras):
        try:
            surface = image_samples(mesh, cam)
        except ValueError as err:
            raise ValueError(f"camera {v}: {err}") from None
        light_vis = light_visibility(mesh, surface, rig, chunk=1 << 18, packed=True)
        cam_vis = camera_visibility(mesh, surface, [cam])
        m = material if isinstance(material, brdf.AbstractBRDF) else material(surface)
        H, W = cam.height, cam.width
        idx = np.asarray(surface.texel_index)
        seen = np.zeros(H * W, bool)
        seen[idx] = cam_vis[0]
        chunk = (int(light_chunk) if light_chunk is not None
                 else max(1, min(_LIGHT_CHUNK, _CHUNK_PIXEL_LIGHTS // max(1, surface.num_samples))))
        for _, ls, _, rad, msk in simulate_chunks(surface, rig, [cam], m, light_vis, cam_vis, light_chunk=chunk,
                                                  sample_chunk=surface.num_samples):
            r, _ = sense_keyed(sensor, seed, rad, msk, view=v, lights=ls.start, samples=idx)
            img = np.zeros((ls.stop - ls.start, H * W, C), np.float32)
            img[:, idx] = r
            img[:, ~seen] = 0.0
            yield ImageChunk(v, ls, img.reshape(-1, H, W, C), seen.reshape(H, W))
            bar.advance(ls.stop - ls.start)


def simulate_images(mesh: Mesh, rig: Rig, cameras, material: brdf.AbstractBRDF | Callable[[Surface], brdf.AbstractBRDF],
                    *, sensor: Sensor | None = None, seed=0, progress=None) -> tuple[list, list]:
    """Simulate the photographs of an OLAT capture: per camera, one image per light, in memory.

    :func:`iter_images` gathered into whole stacks (the same photographs, the same noise); for a capture larger
    than memory, write the chunks as they come instead (``relight.io.PhotoCaptureWriter``).

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
    images, masks = [], []
    for view, lights, img, mask in iter_images(mesh, rig, cameras, material, sensor=sensor, seed=seed,
                                               progress=progress):
        if view == len(images):
            images.append(np.zeros((rig.num_lights, *img.shape[1:]), np.float32))
            masks.append(mask)
        images[view][lights] = img
    return images, masks
