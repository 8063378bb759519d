"""An OLAT simulation streamed into a writer block by block, with keyed sensor noise.

``simulate_into`` cuts the sample grid into blocks, and per block ray-casts the
light visibility of its samples, runs ``simulate_chunks`` on them, applies the
sensor (``sense_keyed``: each observation's noise a function of (seed, view,
light, sample) only) and hands every chunk, scattered onto the block's stretch
of the grid, to ``writer.write``. Memory is bounded by the block, not by the
grid; the kernels compile once across blocks (every block's samples are padded
to one length).
"""

from __future__ import annotations

import time
from typing import NamedTuple, Protocol, runtime_checkable

import jax
import numpy as np

import brdf

from ._camera import Camera
from ._host import host_fields, host_subset
from ._mesh import Mesh
from ._progress import Phase
from ._rig import Rig
from ._sensor import Sensor, sense_keyed
from ._simulate import Subsurface, simulate_chunks
from ._surface import Surface
from ._visibility import light_visibility

# Grid samples per block by default: one capture-store chunk's width (relight.io's 2 MiB of 8 RGB float32
# lights), so a store's blocks write whole chunks.
DEFAULT_BLOCK = 1 << 14
# With several blocks, each block's samples are padded (repeating its last) to the largest block's count
# rounded up to this, so the kernels compile once for every block.
_PAD_SAMPLES = 128
# Rays per light-visibility call.
_RAY_CHUNK = 1 << 18


@runtime_checkable
class CaptureWriter(Protocol):
    """What ``simulate_into`` writes to: one method,
    ``write(view, lights, samples, radiance, mask)`` with ``view`` an int,
    ``lights`` and ``samples`` slices of the capture's light and sample axes,
    ``radiance`` float32 [nL, nS, C] and ``mask`` bool [nL, nS] (NumPy). Every
    element of the capture [V, L, S, C] is written exactly once, in any order.
    ``relight.io.CaptureStoreWriter`` and ``relight.io.CaptureFolderWriter`` are two."""

    def write(self, view: int, lights: slice, samples: slice, radiance: np.ndarray, mask: np.ndarray) -> None: ...


class StreamSummary(NamedTuple):
    """What ``simulate_into`` reports beside what it wrote.

    Fields:
        all_lights: float32 [S, C]: view 0's capture summed over the lights (every
            light on), on the sample grid (a preview).
        blocks: the number of blocks the grid was cut into.
        block: samples of the grid per block.
        visibility_s: seconds spent ray-casting the light visibility.
    """

    all_lights: np.ndarray
    blocks: int
    block: int
    visibility_s: float


def _host_tree(tree, P: int):
    """The per-sample array leaves of a brdf Module (leading axis P) as NumPy; shared leaves kept."""
    shared = lambda x: isinstance(x, brdf.AbstractBRDF) and not x.per_sample  # noqa: E731
    return jax.tree_util.tree_map(
        lambda x: x if shared(x) else (np.asarray(x) if hasattr(x, "ndim") and x.ndim >= 1 and x.shape[0] == P
                                       else x), tree, is_leaf=shared)


def _take_host(tree, P: int, idx):
    """Rows ``idx`` of the NumPy per-sample leaves of :func:`_host_tree`, put on the device (no JAX program)."""
    shared = lambda x: isinstance(x, brdf.AbstractBRDF) and not x.per_sample  # noqa: E731
    return jax.tree_util.tree_map(
        lambda x: x if shared(x) else (jax.device_put(x[idx]) if isinstance(x, np.ndarray) and x.ndim >= 1
                                       and x.shape[0] == P else x), tree, is_leaf=shared)


def simulate_into(writer: CaptureWriter, mesh: Mesh, surface: Surface, rig: Rig, cameras,
                  material: brdf.AbstractBRDF | None, camera_visibility, *, subsurface: Subsurface | None = None,
                  sensor: Sensor | None = None, seed=0, block: int = DEFAULT_BLOCK, light_chunk: int = 16,
                  progress=None) -> StreamSummary:
    """Simulate an OLAT capture of ``surface``'s grid and stream it into ``writer``, block by block.

    The capture written is [V, L, H*W, C] on the whole sample grid of
    ``surface.resolution`` (H, W): grid samples without a surface sample are 0
    and invalid. Per block of ``block`` grid samples: the light visibility of the
    block's samples (``light_visibility``), ``simulate_chunks`` in chunks of
    ``light_chunk`` lights, the sensor (``sense_keyed``, so the noise does not
    depend on ``block`` or ``light_chunk``), and one ``writer.write`` per
    (view, light chunk). With ``subsurface`` the operator couples every sample,
    so there is one block, the whole grid.

    Args:
        writer: a :class:`CaptureWriter` (e.g. ``relight.io.CaptureStoreWriter``).
        mesh: the mesh the samples lie on (the occluder of the light visibility).
        surface: the P samples (e.g. the seen texels of ``texel_samples``), with
            ``texel_index`` strictly increasing.
        rig: the L lights.
        cameras: one ``Camera`` or a sequence of V.
        material: a brdf Module with per-sample parameters [P, ...] (or shared ones), or None
            (with ``subsurface``).
        camera_visibility: bool [V, P] (``camera_visibility``).
        subsurface: optional ``Subsurface`` on the same P samples.
        sensor: optional ``Sensor``; None: noise-free radiance (clipped at 0).
        seed: the noise seed (``observation_key``).
        block: grid samples per block (>= 1); peak memory grows with it.
        light_chunk: lights per ``simulate_chunks`` chunk and per write.
        progress: ``Progress``, phase "simulate", counting (view, light) images per block.

    Returns:
        A :class:`StreamSummary` (view 0 with every light on, the block count, the block
        size, the seconds of light visibility).
    """
    cameras = (cameras,) if isinstance(cameras, Camera) else tuple(cameras)
    H, W = surface.resolution
    S, P = H * W, surface.num_samples
    V, L = len(cameras), rig.num_lights
    fields = host_fields(surface)
    tex = np.asarray(fields["texel_index"], np.int64)
    if P == 0 or np.any(np.diff(tex) <= 0) or tex[0] < 0 or tex[-1] >= S:
        raise ValueError(f"simulate_into: surface.texel_index must be strictly increasing in [0, {S}) "
                         f"(one sample per grid sample, in grid order), with at least one sample")
    cv = np.asarray(camera_visibility, bool)
    if cv.shape != (V, P):
        raise ValueError(f"simulate_into: camera_visibility must have shape [V, P] = {(V, P)}, got {cv.shape}")
    if int(block) < 1 or int(light_chunk) < 1:
        raise ValueError(f"simulate_into: block ({block}) and light_chunk ({light_chunk}) must be >= 1")
    block = S if subsurface is not None else int(block)
    lc = int(light_chunk)
    host_material = _host_tree(material, P)
    edges = np.unique(np.arange(0, S + block, block).clip(max=S))
    starts = np.searchsorted(tex, edges)  # the samples of block k: starts[k]:starts[k + 1]
    counts = np.diff(starts)
    # Every block's samples padded to one length (repeating its last): the kernels compile once.
    pad_to = int(counts.max()) if len(counts) == 1 or subsurface is not None else (
        -(-int(counts.max()) // _PAD_SAMPLES) * _PAD_SAMPLES)
    C = None
    all_on = None
    t_vis = 0.0
    bar = Phase(progress, "simulate", V * L * len(counts))
    for k, n in enumerate(counts):
        g0, g1 = int(edges[k]), int(edges[k + 1])
        if n == 0:  # no sample here: zeros, invalid
            C = int(np.asarray(rig.intensity).shape[-1])
            for v in range(V):
                for l0 in range(0, L, lc):
                    nl = min(lc, L - l0)
                    writer.write(v, slice(l0, l0 + nl), slice(g0, g1), np.zeros((nl, g1 - g0, C), np.float32),
                                 np.zeros((nl, g1 - g0), bool))
                    bar.advance(nl)
            continue
        rows = np.arange(starts[k], starts[k + 1])
        pad = np.minimum(np.arange(starts[k], starts[k] + pad_to), starts[k + 1] - 1)
        t1 = time.perf_counter()
        lv = light_visibility(mesh, host_subset(fields, (H, W), rows), rig, chunk=_RAY_CHUNK)
        t_vis += time.perf_counter() - t1
        lv = lv[np.minimum(np.arange(pad_to), n - 1)]
        if subsurface is not None or pad_to == P:
            sub, mat = surface, material
        else:
            sub, mat = host_subset(fields, (H, W), pad), _take_host(host_material, P, pad)
        local = tex[rows] - g0
        for v, ls, _, rad, msk in simulate_chunks(sub, rig, cameras, mat, lv, cv[:, pad], light_chunk=lc,
                                                  sample_chunk=pad_to, subsurface=subsurface):
            r, m = sense_keyed(sensor, seed, rad, msk, view=v, lights=ls.start, samples=tex[pad])
            nl, C = ls.stop - ls.start, r.shape[-1]
            dense, dmask = np.zeros((nl, g1 - g0, C), np.float32), np.zeros((nl, g1 - g0), bool)
            dense[:, local], dmask[:, local] = r[:, :n], m[:, :n]
            writer.write(v, ls, slice(g0, g1), dense, dmask)
            if v == 0:
                if all_on is None:
                    all_on = np.zeros((S, C), np.float32)
                all_on[g0:g1] += dense.sum(axis=0)
            bar.advance(nl)
    return StreamSummary(all_on, int(len(counts)), int(block), t_vis)

