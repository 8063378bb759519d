"""``Lights``, the "lights" method: the environment cut into regions of
equal energy by median cut (Debevec 2005, "A Median Cut Algorithm for Light
Probe Sampling"), each region a distant light at its energy centroid carrying
the region's integral of radiance.

    L_o(x, wo) ~= sum_k f_r(x, w_k, wo) max(0, n.w_k) V(x, w_k) Phi_k,
    Phi_k = int_{region k} L_env dw   (per channel),
    w_k   = normalize(int_{region k} Y(w) w dw)   (Y the luminance)

The partition is a k-d tree over the lat-long pixels: the region of largest
energy (luminance x solid angle) is split in two of equal energy across its
longer side (the width measured at its middle latitude, Debevec's cos(latitude)
rule), until there are K regions; a region of one pixel is not split. As K
grows the regions shrink to single pixels and the sum becomes the midpoint rule
of the map at its full resolution ("dense" at the map's own rows), so the
method converges; unlike "dense"'s uniform grid it spends its directions where
the light is (many on a sun, few on a dark floor).
"""

from __future__ import annotations

import heapq
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

import stage

from ._abstract import int_at_least
from ._directional import AbstractDirectional, DirectionalGeometry, direction_visibility
from ._shading import concrete

__all__ = ["Lights", "LightsLighting", "median_cut", "region_strength"]

# Rec. 709 luminance, as relight.envmap's importance sampling weighs pixels.
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def _solid_angles(h: int, w: int) -> np.ndarray:
    """[H] solid angle of one pixel in each row, (2 pi / W)(cos theta_i - cos theta_i+1)."""
    i = np.arange(h)
    return (2 * np.pi / w) * 2 * np.sin(np.pi * (i + 0.5) / h) * np.sin(np.pi / (2 * h))


def _pixel_directions(h: int, w: int) -> np.ndarray:
    """[H, W, 3] pixel-centre directions (relight.envmap.latlong_directions, in NumPy float64)."""
    theta = np.pi * (np.arange(h) + 0.5) / h
    phi = 2 * np.pi * (np.arange(w) + 0.5) / w - np.pi
    st, ct = np.sin(theta)[:, None], np.cos(theta)[:, None]
    return np.stack(np.broadcast_arrays(st * np.sin(phi)[None], ct, -st * np.cos(phi)[None]), axis=-1)


def median_cut(radiance: np.ndarray, n_lights: int) -> tuple[np.ndarray, np.ndarray]:
    """Median-cut partition of a lat-long map [H, 2H, C] into ``n_lights``
    rectangles of (nearly) equal energy (Debevec 2005; the largest region is
    split first, so any K, not only powers of two). Returns (labels [H, W]
    int32 in [0, K), directions [K, 3] unit float64: each region's
    luminance-weighted mean direction, or its solid-angle mean when it holds no
    energy). K = min(n_lights, H W). Pure NumPy on a concrete map."""
    rad = np.asarray(radiance, np.float64)
    h, w, c = rad.shape
    lum = rad @ _LUMA if c == 3 else rad.mean(-1)
    dom = np.broadcast_to(_solid_angles(h, w)[:, None], (h, w))
    e = np.maximum(lum, 0.0) * dom
    sat = np.zeros((h + 1, w + 1))
    sat[1:, 1:] = np.cumsum(np.cumsum(e, 0), 1)

    def energy(r0, r1, c0, c1):
        return sat[r1, c1] - sat[r0, c1] - sat[r1, c0] + sat[r0, c0]

    k_max = min(int(n_lights), h * w)
    # Max-heap on energy (ties broken by area, so a black map still splits evenly).
    heap = [(-energy(0, h, 0, w), -h * w, 0, (0, h, 0, w))]
    done, count = [], 1
    while heap and len(done) + len(heap) < k_max:
        _, _, _, (r0, r1, c0, c1) = heapq.heappop(heap)
        if (r1 - r0) * (c1 - c0) == 1:
            done.append((r0, r1, c0, c1))
            continue
        mid = 0.5 * (r0 + r1) / h * np.pi
        tall = (r1 - r0) * (np.pi / h) >= (c1 - c0) * (2 * np.pi / w) * np.sin(mid)
        by_col = (r1 - r0 == 1) or (c1 - c0 > 1 and not tall)
        if by_col:
            cum = sat[r1, c0 + 1:c1 + 1] - sat[r0, c0 + 1:c1 + 1] - sat[r1, c0] + sat[r0, c0]
            lo, hi = c0, c1
        else:
            cum = sat[r0 + 1:r1 + 1, c1] - sat[r0 + 1:r1 + 1, c0] - sat[r0, c1] + sat[r0, c0]
            lo, hi = r0, r1
        tot = cum[-1]
        cut = lo + 1 + int(np.searchsorted(cum[:-1], 0.5 * tot)) if tot > 0 else (lo + hi) // 2
        cut = min(max(cut, lo + 1), hi - 1)
        parts = ((r0, r1, c0, cut), (r0, r1, cut, c1)) if by_col else ((r0, cut, c0, c1), (cut, r1, c0, c1))
        for p in parts:
            heapq.heappush(heap, (-energy(*p), -(p[1] - p[0]) * (p[3] - p[2]), count, p))
            count += 1
    regions = done + [item[3] for item in heap]
    labels = np.empty((h, w), np.int32)
    for k, (r0, r1, c0, c1) in enumerate(regions):
        labels[r0:r1, c0:c1] = k
    d = _pixel_directions(h, w).reshape(-1, 3)
    lab = labels.reshape(-1)
    K = len(regions)
    mean_e = np.stack([np.bincount(lab, (e.reshape(-1) * d[:, i]), K) for i in range(3)], -1)
    mean_a = np.stack([np.bincount(lab, (dom.reshape(-1) * d[:, i]), K) for i in range(3)], -1)
    has = np.linalg.norm(mean_e, axis=1) > 1e-300
    dirs = np.where(has[:, None], mean_e, mean_a)
    nrm = np.linalg.norm(dirs, axis=1, keepdims=True)
    # A region symmetric about the pole (a full ring) has a zero mean vector: take its middle pixel.
    mid_pix = np.array([d[(r0 + r1) // 2 * w + (c0 + c1) // 2] for (r0, r1, c0, c1) in regions])
    dirs = np.where(nrm > 1e-12, dirs / np.maximum(nrm, 1e-300), mid_pix)
    return labels, dirs


def region_strength(radiance: Float[Array, "H W C"], labels: np.ndarray, n_regions: int) -> Float[Array, "K C"]:
    """Phi_k = sum over region k of L dOmega [K, C] (the exact integral of the
    piecewise-constant map over the region), differentiable in ``radiance``."""
    rad = jnp.asarray(radiance)
    h, w, c = rad.shape
    dom = jnp.asarray(_solid_angles(h, w), rad.dtype)[:, None, None]
    return jax.ops.segment_sum((rad * dom).reshape(-1, c), jnp.asarray(labels.reshape(-1)), num_segments=n_regions)


class LightsLighting(eqx.Module):
    """``Lights``' prepared lighting: the lights' directions ``dirs`` [K, 3] (of the unrotated map)
    and their region integrals ``strength`` [K, C]."""

    dirs: np.ndarray
    strength: Any
    dtype: Any = eqx.field(static=True)


class Lights(AbstractDirectional):
    """The environment cut by median cut into ``lights`` regions of equal energy.

    Each region is a distant light at its energy centroid carrying the region's exact integral, with
    ray-cast visibility per light (``lights`` rays per sample). Converges to the midpoint rule of the
    map at its full resolution as ``lights`` grows (see the module docstring). An environment
    rotation moves the lights (exact, nothing resampled); their shadows are then cast anew.

    Args:
        lights: the number of regions (>= 1).

    References:
        Debevec 2005, "A Median Cut Algorithm for Light Probe Sampling".
    """

    lights: int = 256

    name: ClassVar[str] = "lights"
    KEYWORDS: ClassVar[dict[str, str]] = {"lights": "lights"}

    def __check_init__(self):
        int_at_least("lights", "lights", self.lights, 1)

    def prepare(self, env, *, dtype=jnp.float32) -> LightsLighting:
        radiance = jnp.asarray(env.radiance, dtype)
        # The partition (and the light directions) come from the map's values without gradient; the
        # strengths are exact region integrals of the radiance, so derivatives flow to every pixel.
        with jax.ensure_compile_time_eval():
            conc = concrete(jax.lax.stop_gradient(radiance))
        if conc is None:
            raise ValueError("method 'lights' cuts the environment into regions from its values: pass a concrete "
                             "env (not traced under jit); gradients with respect to it still flow")
        labels, dirs = median_cut(conc, self.lights)
        return LightsLighting(dirs, region_strength(radiance, labels, len(dirs)).astype(dtype), dtype)

    def num_directions(self, lighting: LightsLighting) -> int:
        return int(lighting.dirs.shape[0])

    def light_set(self, lighting: LightsLighting, rotation):
        d = jnp.asarray(lighting.dirs, lighting.dtype)
        # Light from d arrives from R d (row vectors: d R^T); exact, nothing is resampled.
        return (d if rotation is None else d @ jnp.asarray(rotation, lighting.dtype).T), lighting.strength, False

    def visibility_under(self, lighting: LightsLighting, geometry: DirectionalGeometry, light, rotation):
        """The cached visibility, or under a rotation (the lights moved with the environment) their
        shadows cast anew."""
        if rotation is None:
            return geometry.vis
        if geometry.mesh is not None:
            return stage.PackedMask.pack(direction_visibility(geometry.mesh, geometry.surface,
                                                              np.asarray(light, np.float64), geometry.terminator))
        if geometry.vis is not None:
            raise ValueError("method 'lights' with a rotation moves its lights: pass mesh= to cast their shadows "
                             "(a given visibility= holds the unrotated lights' shadows)")
        return geometry.vis
