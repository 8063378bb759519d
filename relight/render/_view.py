"""Novel views and turntables rendered from texel-space material maps.

A view casts one primary ray per sub-pixel (``stage.image_samples``), looks the
texel-space maps up at the hit's uv (bilinear in texture space, after
dilating the charts by two texels so lookups at chart borders do not blend in
empty texels; the model map by nearest texel), shades the hits with
:func:`relight.render.render_samples`' machinery and box-filters the
``supersample`` x ``supersample`` sub-pixels down (anti-aliasing). Rays that
miss the mesh see the environment (bilinear lookup), or black.

The subsurface term's radiant exitance M does not depend on the view: it is
computed once on the texel samples (where the diffusion operator couples
neighbours over the whole surface, not only the visible pixels) and looked up
per pixel like a map.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import stage

from ..envmap._latlong import EnvMap, rotation_matrix, sample_latlong
from ..image._preview import dilate, row_bands, sample_texture
from ..materials._maps import SUBSURFACE, MaterialMaps
from ._abstract import AbstractMethod
from ._methods import _settings
from ._shading import build_operator, check_inputs

__all__ = ["orbit_camera", "render_view", "scaled_camera", "turntable", "y_rotations"]

_DILATE_TEXELS = 2


@dataclasses.dataclass
class _View:
    """Everything about one camera view that does not depend on the lighting: the pixel samples (hits only, or
    None without any), the hit mask and, per group of samples (``_Renderer._group``), the maps, view directions and
    the method's geometry once computed (``turntable`` keeps them across frames)."""

    camera: stage.Camera
    surface: stage.Surface | None  # pixel samples (hits only; padded to whole groups)
    hit: np.ndarray                # [H s, W s] bool
    uv: np.ndarray | None          # [P, 2]
    group: int                     # samples per group (the last one padded by repeating the last sample)
    cache: dict | None = None      # group index -> (maps, wo, geometry), when kept


# A band's pixel samples are worked in groups of a fixed count, 1 / _BUCKETS of the band's sub-pixels (the last
# group padded by repeating the last sample): every group of every band has one shape, so the maps' lookups,
# the geometry and the shading compile (and JAX keeps) one program per operation, not one per band's hit count,
# and at most one group of samples is repeated per band.
_BUCKETS = 8


def _textures(maps: MaterialMaps, texel_surface: stage.Surface) -> dict[str, np.ndarray]:
    """The maps on the texel grid, float32, dilated by two texels; the model map as float32 [H, W, 1]."""
    valid = np.zeros(texel_surface.resolution, bool).ravel()
    valid[np.asarray(texel_surface.texel_index)] = True
    valid = valid.reshape(texel_surface.resolution)
    tex = {}
    for name in ("rho_d", "rho_s", "alpha", "normal", "tangent", "mfp"):
        tex[name] = dilate(texel_surface.to_texture(np.asarray(getattr(maps, name), np.float32)), valid,
                           _DILATE_TEXELS)
    model = texel_surface.to_texture(np.asarray(maps.model, np.float32)[:, None])
    tex["model"] = dilate(model, valid, _DILATE_TEXELS)
    return tex


def _nearest(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    h, w = texture.shape[:2]
    x = np.clip(np.floor(uv[..., 0] * w), 0, w - 1).astype(int)
    y = np.clip(np.floor((1 - uv[..., 1]) * h), 0, h - 1).astype(int)
    return texture[y, x]


def _lookup_maps(tex: dict, uv: np.ndarray, surface: stage.Surface, dt) -> MaterialMaps:
    look = {k: sample_texture(v, uv) for k, v in tex.items() if k != "model"}
    n = look["normal"]
    bad = np.linalg.norm(n, axis=1) < 1e-6
    n = np.where(bad[:, None], np.asarray(surface.normal), n)  # outside every chart: the geometric normal
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    tg = look["tangent"]
    tg = tg - np.sum(tg * n, 1, keepdims=True) * n
    bad = np.linalg.norm(tg, axis=1) < 1e-6
    tg = np.where(bad[:, None], np.asarray(surface.tangent), tg)
    tg = tg / np.linalg.norm(tg, axis=1, keepdims=True)
    model = np.rint(_nearest(tex["model"], uv)[:, 0]).astype(np.int32)
    alpha = np.maximum(look["alpha"], 1e-4)  # brdf.ALPHA_MIN: bilinear blends never reach 0, but be safe
    # device_put of host arrays already in the dtype: jnp.asarray compiles (and keeps) a program per new shape.
    j = lambda x: jax.device_put(np.asarray(x, dt))  # noqa: E731
    return MaterialMaps(j(np.maximum(look["rho_d"], 0)), j(np.maximum(look["rho_s"], 0)), j(alpha), j(n), j(tg),
                        j(np.maximum(look["mfp"], 0)), jax.device_put(model))


def _view(mesh: stage.Mesh, camera: stage.Camera, supersample: int, group: int | None = None) -> _View:
    """The pixel samples of ``camera``: one ray cast (``stage.image_samples``; the hit mask is their pixels).
    ``group``: samples per group, their count padded (the last sample repeated) to a multiple of it (None: one
    group of every sample)."""
    s = int(supersample)
    hit = np.zeros((camera.height * s, camera.width * s), bool)
    try:
        surf = stage.image_samples(mesh, camera, s)
    except ValueError as e:  # no ray hits the mesh: the image is the background
        if "sees no part" not in str(e):
            raise
        return _View(camera, None, hit, None, 0)
    hit.reshape(-1)[np.asarray(surf.texel_index)] = True
    n = surf.num_samples
    if group is None:
        group = n
    elif n % group:
        surf = surf.take(np.minimum(np.arange(-(-n // group) * group), n - 1))
    return _View(camera, surf, hit, np.asarray(surf.uv, np.float64), group)


def _ray_dirs(camera: stage.Camera, supersample: int) -> np.ndarray:
    """float64 [H s * W s, 3]: the primary rays' directions (for the background)."""
    s = int(supersample)
    h, w = camera.height * s, camera.width * s
    ys, xs = np.meshgrid((np.arange(h) + 0.5) / s, (np.arange(w) + 0.5) / s, indexing="ij")
    _, d = camera.rays(np.stack([xs, ys], -1).reshape(-1, 2).astype(np.float64))
    return np.broadcast_to(np.asarray(d, np.float64), (h * w, 3))


def _check_view_args(maps, texel_surface, mesh, camera, env, supersample):
    check_inputs(maps, texel_surface, env)
    if not isinstance(mesh, stage.Mesh):
        raise ValueError(f"mesh must be a stage.Mesh, got {type(mesh).__name__}")
    if mesh.uv is None:
        raise ValueError(f"mesh '{mesh.name}' has no UV coordinates: the texel-space maps cannot be looked up")
    if not isinstance(camera, stage.Camera):
        raise ValueError(f"camera must be a stage.Camera, got {type(camera).__name__}")
    if not isinstance(supersample, (int, np.integer)) or isinstance(supersample, bool) or supersample < 1:
        raise ValueError(f"supersample must be an integer >= 1, got {supersample!r}")


class _Renderer:
    """Shared state of render_view / turntable: lighting (env-dependent),
    texel-space textures and, for subsurface maps, the texel-space geometry."""

    def __init__(self, maps, texel_surface, mesh, env, method, settings, progress):
        self.s = _settings(method, settings)
        self.method = self.s["method"]
        self.dt = self.s["dtype"]
        self.maps, self.texel_surface, self.mesh, self.env = maps, texel_surface, mesh, env
        self.progress = lambda phase: stage.Phase(progress, phase)
        self.progress("lighting")
        self.lt = self.method.prepare(env, dtype=self.dt)
        self.tex = _textures(maps, texel_surface)
        model = np.asarray(maps.model)
        self.has_sss = bool(np.any(model == SUBSURFACE))
        self.tex_geo = None
        self.op = None

    def view(self, camera, supersample, group: int | None = None, keep: bool = False) -> _View:
        """The pixel samples of ``camera`` (:func:`_view`); ``keep``: their maps and geometry kept once computed,
        for views shaded again (``turntable``'s environment rotations)."""
        self.progress("primary rays and maps")
        v = _view(self.mesh, camera, supersample, group)
        v.cache = {} if keep else None
        return v

    def _group(self, v: _View, g: int):
        """Group ``g`` of a view's samples: (surface, maps, wo toward the camera, geometry), computed (or kept)."""
        if v.cache is not None and g in v.cache:
            return v.cache[g]
        sl = slice(g * v.group, (g + 1) * v.group)
        surf = v.surface if v.group == v.surface.num_samples else v.surface.take(np.arange(sl.start, sl.stop))
        maps = _lookup_maps(self.tex, v.uv[sl], surf, self.dt)
        wo = v.camera.view_directions(jax.device_put(np.asarray(surf.position, self.dt)))
        self.progress("visibility")
        geo = self.method.geometry(self.lt, maps, surf, self.mesh, terminator=self.s["terminator"])
        out = (surf, maps, wo, geo)
        if v.cache is not None:
            v.cache[g] = out
        return out

    def exitance_texture(self, rotation, key):
        """Subsurface exitance M on the texel grid [H, W, C] (None without subsurface samples)."""
        if not self.has_sss:
            return None
        self.progress("subsurface (texel space)")
        if self.tex_geo is None:
            self.tex_geo = self.method.geometry(self.lt, self.maps, self.texel_surface, self.mesh,
                                                terminator=self.s["terminator"])
            self.op = self.s["operator"] or build_operator(self.maps, self.texel_surface)
        wo = self.maps.frame(self.texel_surface).normal
        _, M = self.method.shade(self.lt, self.tex_geo, self.maps, self.texel_surface, wo, rotation=rotation, key=key,
                                 eta=self.s["eta"], chunk=self.s["chunk"], operator=self.op)
        # Only subsurface texels hold an exitance: a pixel on the subsurface rung next to a texel on
        # another rung must not blend that texel's 0 in (dark seams where the rungs meet), so the
        # others are filled from their subsurface neighbours, as chart borders are.
        valid = np.zeros(self.texel_surface.resolution, bool).ravel()
        idx = np.asarray(self.texel_surface.texel_index)
        valid[idx[np.asarray(self.maps.model) == SUBSURFACE]] = True
        tex = self.texel_surface.to_texture(np.asarray(M, np.float32))
        return dilate(tex, valid.reshape(self.texel_surface.resolution), _DILATE_TEXELS)

    def image(self, v: _View, supersample, background, rotation, key, m_tex) -> np.ndarray:
        """The view shaded under the (rotated) environment, group by group of its samples, box-filtered to the
        camera's pixels. ``key`` is folded with the group's index when there are several."""
        camera = v.camera
        s = int(supersample)
        hs, ws = v.hit.shape
        C = self.env.radiance.shape[-1]
        img = np.zeros((hs * ws, C), np.float32)
        if background:
            d = _ray_dirs(camera, s)
            if rotation is not None:
                d = d @ np.asarray(rotation, np.float64)  # R^T d
            img[:] = np.asarray(sample_latlong(self.env.radiance, jnp.asarray(d, self.dt)), np.float32)
        if v.surface is not None:
            groups = v.surface.num_samples // v.group
            for g in range(groups):
                surf, maps, wo, geo = self._group(v, g)
                self.progress("shading")
                sl = slice(g * v.group, (g + 1) * v.group)
                sss = None if m_tex is None else jax.device_put(np.asarray(sample_texture(m_tex, v.uv[sl]), self.dt))
                kg = key if key is None or groups == 1 else jax.random.fold_in(key, g)
                rad, _ = self.method.shade(self.lt, geo, maps, surf, wo, rotation=rotation, key=kg,
                                           eta=self.s["eta"], chunk=self.s["chunk"], operator=self.s["operator"],
                                           sss_exitance=sss)
                img[np.asarray(surf.texel_index)] = np.asarray(rad, np.float32)
                del surf, maps, wo, geo, rad
        img = img.reshape(camera.height, s, camera.width, s, C).mean(axis=(1, 3))
        return np.where(np.isfinite(img), img, 0.0).astype(np.float32)


def render_view(maps: MaterialMaps, texel_surface: stage.Surface, mesh: stage.Mesh, camera: stage.Camera, env: EnvMap,
                *, method: str | AbstractMethod = "rig", supersample: int = 2, background: bool = True, key=None,
                progress: stage.Progress | None = None, **settings) -> np.ndarray:
    """The texel-space maps on the mesh as a camera sees them under an environment map.

    Primary visibility by ray casting (``stage.image_samples`` on a ``supersample`` x ``supersample``
    sub-pixel grid), maps bilinear in texture space at the hits' uv, shading by ``method`` with
    shadows cast by ``mesh`` (the method's ``prepare``, ``geometry`` and ``shade``), box filter down
    to the camera's pixels. The subsurface exitance is computed on the texel samples and looked up
    per pixel. Visibility is per pixel sample: cost grows with (W H supersample^2) x directions for
    the directional methods and x samples for ``Reference``; memory is one band's: an image of more than
    ``relight.image.BAND_RAYS`` sub-pixel samples is rendered in bands of rows (``stage.Camera.crop``), each band's
    samples in groups of one count (so one compiled program per operation serves every band), the same pixels (a
    ``Reference`` key is folded with the band's index, then the group's).

    Args:
        maps: ``relight.MaterialMaps`` over ``texel_surface``.
        texel_surface: the maps' samples (``stage.texel_samples(mesh, ...)`` or its covered subset).
        mesh: ``stage.Mesh`` with UVs.
        camera: ``stage.Camera``.
        env: ``relight.envmap.EnvMap``.
        method: a method Module (``Rig``, ``Dense``, ``Lights``, ``Fast``, ``Reference``) or its string
            spelling with its keyword settings (see :func:`relight.render.render_samples`).
        supersample: sub-pixels per pixel side (>= 1).
        background: rays that miss see the (rotated) environment, else 0.
        key: ``jax.random`` key of ``Reference``.
        progress: ``progress(phase, 0, None)`` (``stage.Progress``), called as each phase starts.
        **settings: the shared settings of :func:`relight.render.render_samples` (``rotation``,
            ``eta``, ``chunk``, ``operator``, ``dtype``, ``terminator``).

    Returns:
        float32 [H, W, 3] radiance (the environment's units).
    """
    _check_view_args(maps, texel_surface, mesh, camera, env, supersample)
    r = _Renderer(maps, texel_surface, mesh, env, method, settings, progress)
    rotation = r.s["rotation"]
    bands = list(row_bands(camera, supersample))
    if len(bands) == 1:
        v = r.view(camera, supersample)
        return r.image(v, supersample, background, rotation, key, r.exitance_texture(rotation, key))
    # In bands of rows (``stage.Camera.crop``), each in groups of one sample count: the pixel samples' surface,
    # maps, visibility and shading are one group's, whatever the image size; the lighting and the texel-space
    # exitance are shared.
    m_tex = r.exitance_texture(rotation, key)
    out = np.empty((camera.height, camera.width, env.radiance.shape[-1]), np.float32)
    group = max(1, bands[0][1].height * camera.width * supersample * supersample // _BUCKETS)
    for b, (r0, band) in enumerate(bands):
        kb = None if key is None else jax.random.fold_in(key, b)  # independent Monte Carlo samples per band
        v = r.view(band, supersample, group=group)
        out[r0:r0 + band.height] = r.image(v, supersample, background, rotation, kb, m_tex)
        del v
        stage.release_freed_memory()  # the band's samples and rays, so the next band reuses the pages
    return out


def orbit_camera(camera: stage.Camera, angle: float, axis=(0.0, 1.0, 0.0)) -> stage.Camera:
    """``camera`` moved around the world origin (the rig centre) by ``angle``
    radians about ``axis``, still looking at the same (rotated) point:
    R' = R Q^T, t' = t, so its centre becomes Q c."""
    Q = rotation_matrix(jnp.asarray(axis, jnp.float32), jnp.asarray(angle, jnp.float32))
    return eqx.tree_at(lambda c: c.R, camera, jnp.asarray(camera.R @ Q.T.astype(camera.R.dtype)))


def y_rotations(angles_deg) -> np.ndarray:
    """Rotations of the environment about +y (a turntable).

    Args:
        angles_deg: [K] angles in degrees (right-handed about +y).

    Returns:
        float64 [K, 3, 3] rotations R_k: light that arrived from d arrives from R_k d.

    Each angle is reduced modulo 360 first (exact in float64), so any finite angle, 1e308 included, is the
    rotation it names instead of an overflow in the float32 trigonometry; ValueError for NaN or Inf.
    """
    a = np.asarray(angles_deg, np.float64).reshape(-1)
    if not np.all(np.isfinite(a)):
        raise ValueError(f"rotation angles must be finite degrees, got {a[~np.isfinite(a)][:3].tolist()}")
    return np.stack([np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(x)), np.float64)
                     for x in np.mod(a, 360.0)])


def scaled_camera(camera: stage.Camera, size: int) -> stage.Camera:
    """``camera`` resampled to ``size`` pixels on its longer side.

    Width and height are scaled (rounded, aspect kept) and the intrinsics' rows with them (fx, skew,
    cx by the width's factor; fy, cy by the height's), so every pixel sees the same part of the
    scene at the new size. The pose is unchanged.

    Args:
        camera: a ``stage.Camera``.
        size: pixels on the longer side (>= 1).

    Returns:
        The scaled camera (``camera`` itself when its size does not change).
    """
    if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or size < 1:
        raise ValueError(f"size must be an integer >= 1, got {size!r}")
    s = size / max(camera.width, camera.height)
    w, h = max(1, round(camera.width * s)), max(1, round(camera.height * s))
    if (w, h) == (camera.width, camera.height):
        return camera
    scale = np.diag([w / camera.width, h / camera.height, 1.0])
    K = jnp.asarray(scale @ np.asarray(camera.K, np.float64), camera.K.dtype)
    # The distortion acts on normalised coordinates, which scaling the image does not change.
    return stage.Camera(K=K, R=camera.R, t=camera.t, width=w, height=h, orthographic=camera.orthographic,
                        dist=camera.dist)


def turntable(maps: MaterialMaps, texel_surface: stage.Surface, mesh: stage.Mesh, camera: stage.Camera, env: EnvMap,
              *, frames: int = 24, mode: str = "envmap", method: str | AbstractMethod = "rig",
              axis=(0.0, 1.0, 0.0),
              supersample: int = 2, background: bool = True, key=None,
              progress: stage.Progress | None = None, **settings) -> Iterator[np.ndarray]:
    """An iterator over ``frames`` images [H, W, 3] of a full turn (frame k at
    angle 2 pi k / frames about ``axis``, right-handed).

    ``mode="envmap"``: the environment rotates (light from d arrives from
    R_k d), the camera stays. Cached across frames: primary hits, the maps
    looked up at the pixels, the per-pixel visibility (rig/dense visibility
    masks, fast ambient occlusion and bent normals), and the environment's
    precomputation (dense grid, SH coefficients, prefiltered levels and DFG
    table, importance-sampling tables, the median-cut light set); each frame
    only rotates the lookups (for "lights" it rotates the lights and casts
    their shadow rays anew; for "rig" it recomputes the light weights from
    rotated light directions, as ``relight.envmap.rotation_sweep_weights``
    does; for "reference" it
    re-traces its rays; with subsurface samples it recomputes the texel-space
    exitance).

    ``mode="orbit"``: the camera orbits the rig centre (``orbit_camera``), the
    environment stays. Cached: the environment's precomputation and the
    texel-space subsurface exitance (view independent); each frame casts its
    primary rays, looks the maps up and computes visibility anew.

    Other arguments as :func:`render_view`. Arguments are checked when
    ``turntable`` is called, not when the first frame is drawn.
    """
    _check_view_args(maps, texel_surface, mesh, camera, env, supersample)
    if mode not in ("envmap", "orbit"):
        raise ValueError(f"turntable mode must be 'envmap' or 'orbit', got {mode!r}")
    if not isinstance(frames, (int, np.integer)) or isinstance(frames, bool) or frames < 1:
        raise ValueError(f"frames must be an integer >= 1, got {frames!r}")
    if "rotation" in settings:
        raise ValueError("turntable sets the environment rotation itself; pass no 'rotation' setting")
    r = _Renderer(maps, texel_surface, mesh, env, method, settings, progress)
    key = jax.random.PRNGKey(0) if key is None else key
    angles = [2 * math.pi * k / frames for k in range(frames)]

    def envmap_frames():
        v = r.view(camera, supersample, keep=True)
        for k, a in enumerate(angles):
            axis_dt = jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
            rot = np.asarray(rotation_matrix(jnp.asarray(axis, axis_dt),
                                             jnp.asarray(a)), np.float64)
            rot = None if k == 0 else rot
            kk = jax.random.fold_in(key, k)
            yield r.image(v, supersample, background, rot, kk, r.exitance_texture(rot, kk))

    def orbit_frames():
        m_tex = r.exitance_texture(None, key)
        for k, a in enumerate(angles):
            cam = orbit_camera(camera, a, axis)
            v = r.view(cam, supersample)
            yield r.image(v, supersample, background, None, jax.random.fold_in(key, k), m_tex)

    return envmap_frames() if mode == "envmap" else orbit_frames()
