"""A ground-truth skin material from the head scan's own textures: albedo,
specular and normal maps sampled on the surface's texel samples, plus a
spatially varying diffuse mean free path and a region map found from the
geometry (nose, ears, lips).

Pure and numpy-side (the textures are data, not parameters): the result is an
equinox Module of per-sample arrays that ``SkinTruth.maps`` turns into a
:class:`relight.materials.MaterialMaps` with model = SUBSURFACE.

Units: lengths in mm (stage frame x right, y up, z toward the front camera),
reflectances linear and unitless, GGX alpha unitless.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

import stage
from skin_bssrdf import SKIN_ETA

from ._maps import SUBSURFACE, MaterialMaps, material_maps

__all__ = ["ALBEDO_MAX", "ALBEDO_SCALE", "ALPHA_RANGE", "EARS", "F0_SKIN", "LIPS", "NOSE", "REGION_MFP_GAIN",
           "REGION_NAMES", "SKIN", "SKIN_DMFP_MM", "SKIN_ETA", "SPEC_F0_RANGE", "SkinRegions", "SkinTruth",
           "skin_maps", "skin_regions"]

# Skin's refractive index (skin_bssrdf.SKIN_ETA, its one home) also sets the specular: 1.4 gives F0 = 0.028, the
# value d'Eon & Luebke 2007 (GPU Gems 3, ch. 14) use for skin.
# Normal-incidence Fresnel reflectance ((eta - 1) / (eta + 1))^2 = 0.0278 (Schlick's F0).
F0_SKIN = ((SKIN_ETA - 1.0) / (SKIN_ETA + 1.0)) ** 2
# rho_s = F0_SKIN * lerp(SPEC_F0_RANGE, s) for the specular map's value s in [0, 1]: 0.014 .. 0.042. The top,
# 0.042, is F0 of eta = 1.5 (an oily sebum film); the bottom stands for specular occlusion by stubble,
# eyebrows and pores, which the map darkens, rather than for a lower index.
SPEC_F0_RANGE = (0.5, 1.5)
# GGX alpha at s = 0 and s = 1: glossier where the map says shinier (forehead, nose, lips), rougher where it is
# dark (stubble, eyebrows). 0.25 .. 0.45 brackets the microfacet roughness rendered faces use (d'Eon & Luebke 2007
# use Beckmann m ~ 0.3; Weyrich et al. 2006 fit roughness per facial region, of this order).
ALPHA_RANGE = (0.45, 0.25)
# rho_d = min(ALBEDO_SCALE * albedo map, ALBEDO_MAX). The decoded map's median on the face is (0.55, 0.32, 0.27)
# and its 95th percentile red 0.74 (a flat-lit photograph, brighter than a total diffuse albedo): 0.85 puts the
# median red at 0.46, between Jensen et al. 2001's skin1 (0.44) and skin2 (0.63) Rd, and 95 % of the face's red
# below 0.63.
ALBEDO_SCALE = 0.85
# Below 1 so that Burley's dmfp fit (skin_bssrdf.Burley.from_mean_free_path) stays well inside its range.
ALBEDO_MAX = 0.95
# Base diffuse mean free path (Christensen & Burley 2015's dmfp = 1/sigma_tr), mm, R, G, B: red longest. Chosen
# inside (1.0-1.5, 0.5-0.8, 0.25-0.4) mm, the range this project takes as rendered skin's. Jensen et al. 2001's
# in-vivo forearm coefficients give the same ordering with 2.3-4x longer lengths (skin1: 3.7, 1.4, 0.7 mm by the
# dipole's 1/sigma_tr), which would blur the bundled head's small features away.
SKIN_DMFP_MM = (1.2, 0.6, 0.3)

REGION_NAMES = ("skin", "nose", "ears", "lips")
SKIN, NOSE, EARS, LIPS = range(len(REGION_NAMES))
# mfp multiplier per region: thin tissue over cartilage (nose, ears) scatters light farther before it is absorbed
# (the red glow of backlit ears); lips are labelled for per-region fits but keep the base mfp.
REGION_MFP_GAIN = (1.0, 1.5, 2.0, 1.0)

# Region shapes, as fractions of the head width W (ear rim to ear rim, ~95 mm for the bundled head):
# (centre offset from the region's anchor point, ellipsoid radii), both (x, y, z) in units of W.
_NOSE_SHAPE = ((0.0, 0.02, -0.08), (0.14, 0.20, 0.12))
_EAR_SHAPE = ((-0.05, 0.0, 0.0), (0.10, 0.20, 0.15))  # x offset toward the head's centre (mirrored for the left)
_LIPS_SHAPE = ((0.0, -0.03, -0.04), (0.17, 0.08, 0.10))
# Weight 1 inside this normalised ellipsoid radius, 0 beyond the second, smoothstep between: soft region edges.
_FALLOFF = (0.6, 1.2)
# Ear height: the lateral extremes are searched within this fraction of (crown - nose tip) above/below the tip,
# which keeps the wider neck and shoulders of a bust out of the search.
_EAR_BAND = 0.3
# Lips: the front-most point of the midline (|x - nose x| < 0.05 W) between these depths below the nose tip (W).
_LIPS_BAND = (0.10, 0.25)

FILTERS = ("box", "bilinear")


@dataclasses.dataclass(frozen=True)
class SkinRegions:
    """Facial regions found from geometry: ``labels`` [P] (index into
    ``REGION_NAMES``: 0 skin, 1 nose, 2 ears, 3 lips; a sample gets the region
    with the largest weight when it exceeds 0.5), ``weights`` [P, 4] (smooth, in
    [0, 1]; column 0 = 1 - the largest of the others), and the anchor points
    (mm): ``nose_tip``, ``ears`` [2, 3] (right, left outer rim), ``lips``, and
    ``head_width`` (mm, rim to rim) that scales every region."""

    labels: np.ndarray
    weights: np.ndarray
    nose_tip: np.ndarray
    ears: np.ndarray
    lips: np.ndarray
    head_width: float


class SkinTruth(eqx.Module):
    """Ground-truth skin material on P surface samples.

    =========  ============  ======  ==============================================================
    field      shape         unit    meaning
    =========  ============  ======  ==============================================================
    rho_d      [P, 3]        --      total diffuse albedo, linear RGB (Burley's A)
    rho_s      [P, 1]        --      Schlick F0 of the GGX lobe
    alpha      [P, 1]        --      isotropic GGX roughness
    normal     [P, 3]        --      world-space shading normal (normal map applied), unit
    tangent    [P, 3]        --      world-space tangent, re-orthogonalised against ``normal``
    mfp        [P, 3]        mm      diffuse mean free path (Christensen & Burley 2015 dmfp)
    regions    [P]           --      region label (``REGION_NAMES``)
    =========  ============  ======  ==============================================================
    """

    rho_d: Float[Array, "sample 3"]
    rho_s: Float[Array, "sample 1"]
    alpha: Float[Array, "sample 1"]
    normal: Float[Array, "sample 3"]
    tangent: Float[Array, "sample 3"]
    mfp: Float[Array, "sample 3"]
    regions: Int[Array, " sample"]

    def maps(self, surface: stage.Surface) -> MaterialMaps:
        """The material as :class:`MaterialMaps` over ``surface`` (model = SUBSURFACE everywhere)."""
        return material_maps(surface, self.rho_d, self.rho_s, self.alpha, normal=self.normal, tangent=self.tangent,
                             mfp=self.mfp, model=SUBSURFACE)


def skin_maps(surface: stage.Surface, textures: dict, *, mfp=SKIN_DMFP_MM, region_gain=REGION_MFP_GAIN,
              albedo_scale: float = ALBEDO_SCALE, filter: str = "box") -> SkinTruth:
    """Sample skin textures at each sample's uv and build the ground truth.

    Per sample (see ``SkinTruth`` for units):

    * rho_d = min(albedo_scale * albedo, ALBEDO_MAX).
    * rho_s = F0_SKIN * lerp(SPEC_F0_RANGE, s), alpha = lerp(ALPHA_RANGE, s), s = the specular map clipped to
      [0, 1].
    * normal = normalize(t nx + b ny + n nz) with the surface's (t, b = n x t, n): the OpenGL (+Y along b)
      convention; the box-averaged tangent-space vector is renormalised first. tangent = t Gram-Schmidt against it.
    * mfp = ``mfp`` [3] (mm) times, per region, 1 + (gain - 1) * weight (the largest over the regions of
      ``skin_regions``), so the nose and ears scatter farther with smooth transitions.

    Args:
        surface: the samples.
        textures: ``"albedo"`` [H, W, 3] linear, ``"specular"`` [H, W, 1] in [0, 1], ``"normal"`` [H, W, 3] unit
            tangent-space vectors, all with row 0 at v = 1 (``relight.io.head_skin_textures()`` gives the head
            scan's).
        mfp: the diffuse mean free path per channel (mm) [3].
        region_gain: mean-free-path gains of (skin, nose, ears, lips).
        albedo_scale: factor on the albedo texture.
        filter: ``"box"`` averages each texture exactly over the sample's texel footprint on
            ``surface.resolution``'s grid (a summed-area table, bilinear in its corners, so partial texels count by
            area: a 64^2 .. 256^2 grid over a 1024^2 texture is not aliased); ``"bilinear"`` interpolates at the uv
            (for surfaces that are not texel grids, e.g. image samples).

    Returns:
        The ``SkinTruth``.

    Raises:
        ValueError: naming the argument, for missing or malformed textures, non-positive mfp / gains / scale, or
            an unknown filter.
    """
    if filter not in FILTERS:
        raise ValueError(f"skin_maps: filter must be one of {FILTERS}, got {filter!r}")
    if not (np.isfinite(albedo_scale) and albedo_scale > 0):
        raise ValueError(f"skin_maps: albedo_scale must be a positive number, got {albedo_scale!r}")
    base = np.asarray(mfp, np.float64)
    if base.shape != (3,) or not np.all(np.isfinite(base)) or np.any(base <= 0):
        raise ValueError(f"skin_maps: mfp must be 3 positive lengths (mm, R G B), got {mfp!r}")
    gain = np.asarray(region_gain, np.float64)
    if gain.shape != (len(REGION_NAMES),) or not np.all(np.isfinite(gain)) or np.any(gain <= 0):
        raise ValueError(f"skin_maps: region_gain must be {len(REGION_NAMES)} positive factors "
                         f"({', '.join(REGION_NAMES)}), got {region_gain!r}")
    tex = {key: _texture_arg(textures, key, c) for key, c in (("albedo", 3), ("specular", 1), ("normal", 3))}

    uv = np.asarray(surface.uv, np.float64)
    footprint = None if filter == "bilinear" else (1.0 / surface.resolution[1], 1.0 / surface.resolution[0])
    albedo = _lookup(tex["albedo"], uv, footprint)
    spec = np.clip(_lookup(tex["specular"], uv, footprint), 0.0, 1.0)
    n_ts = _unit(_lookup(tex["normal"], uv, footprint))

    t, b, n = (np.asarray(a, np.float64) for a in (surface.tangent, surface.bitangent, surface.normal))
    normal = _unit(t * n_ts[:, 0:1] + b * n_ts[:, 1:2] + n * n_ts[:, 2:3])
    tangent = _unit(t - np.sum(t * normal, axis=1, keepdims=True) * normal)

    rho_d = np.minimum(albedo_scale * np.clip(albedo, 0.0, None), ALBEDO_MAX)
    rho_s = F0_SKIN * (SPEC_F0_RANGE[0] + (SPEC_F0_RANGE[1] - SPEC_F0_RANGE[0]) * spec)
    alpha = ALPHA_RANGE[0] + (ALPHA_RANGE[1] - ALPHA_RANGE[0]) * spec

    regions = skin_regions(surface)
    scale = np.max(1.0 + (gain - 1.0)[None, :] * regions.weights, axis=1, keepdims=True)
    dt = jnp.asarray(surface.position).dtype
    j = lambda x: jnp.asarray(x, dt)  # noqa: E731
    return SkinTruth(rho_d=j(rho_d), rho_s=j(rho_s), alpha=j(alpha), normal=j(normal), tangent=j(tangent),
                     mfp=j(base[None, :] * scale), regions=jnp.asarray(regions.labels, jnp.int32))


def skin_regions(surface: stage.Surface) -> SkinRegions:
    """Nose, ears and lips of a head in the stage frame, found from the sample positions alone.

    The stage frame: x right, y up, z toward the front camera, the head facing +z.

    * nose tip: the front-most (largest z) sample;
    * ears: the lateral extremes (largest and smallest x) within 0.3 x (crown - nose tip) of the nose tip's
      height; their distance is the head width W that sizes every region;
    * lips: the front-most midline sample 0.10-0.25 W below the nose tip.

    Each region is an ellipsoid about its anchor (shapes in units of W, see ``_NOSE_SHAPE`` etc.) with a
    smoothstep falloff between normalised radius 0.6 and 1.2.

    Args:
        surface: samples of a head.

    Returns:
        The ``SkinRegions``.

    Raises:
        ValueError: no ear-height samples are found (not a head in the stage frame).
    """
    p = np.asarray(surface.position, np.float64)
    if p.ndim != 2 or p.shape[0] < 3 or not np.all(np.isfinite(p)):
        raise ValueError("skin_regions: surface.position must be finite [P >= 3, 3] positions (mm)")
    tip = p[np.argmax(p[:, 2])]
    crown = p[:, 1].max()
    band = np.abs(p[:, 1] - tip[1]) <= _EAR_BAND * max(crown - tip[1], 0.0)
    if np.count_nonzero(band) < 2:
        raise ValueError("skin_regions: no samples at ear height; expected a head in the stage frame "
                         "(y up, facing +z) with its nose as the front-most point")
    at_band = p[band]
    ears = np.stack([at_band[np.argmax(at_band[:, 0])], at_band[np.argmin(at_band[:, 0])]])
    width = float(ears[0, 0] - ears[1, 0])
    if not width > 0:
        raise ValueError("skin_regions: the ear-height samples have no lateral extent")
    lo, hi = tip[1] - _LIPS_BAND[1] * width, tip[1] - _LIPS_BAND[0] * width
    mid = (np.abs(p[:, 0] - tip[0]) < 0.05 * width) & (p[:, 1] >= lo) & (p[:, 1] <= hi)
    lips = p[np.flatnonzero(mid)[np.argmax(p[mid, 2])]] if mid.any() else tip - np.array([0.0, 0.17 * width, 0.1])

    def weight(anchor, shape, mirror=1.0):
        offset, radii = (np.asarray(s, np.float64) * width for s in shape)
        centre = anchor + offset * np.array([mirror, 1.0, 1.0])
        q = np.linalg.norm((p - centre) / radii, axis=1)
        return 1.0 - _smoothstep(_FALLOFF[0], _FALLOFF[1], q)

    w = np.zeros((p.shape[0], len(REGION_NAMES)))
    w[:, NOSE] = weight(tip, _NOSE_SHAPE)
    w[:, EARS] = np.maximum(weight(ears[0], _EAR_SHAPE), weight(ears[1], _EAR_SHAPE, mirror=-1.0))
    w[:, LIPS] = weight(lips, _LIPS_SHAPE)
    w[:, SKIN] = 1.0 - w[:, 1:].max(axis=1)
    labels = np.where(w[:, 1:].max(axis=1) > 0.5, 1 + np.argmax(w[:, 1:], axis=1), SKIN).astype(np.int32)
    return SkinRegions(labels=labels, weights=w, nose_tip=tip, ears=ears, lips=lips, head_width=width)


def _smoothstep(e0, e1, x):
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _unit(v):
    # Texture and frame vectors here are unit or close to it; the floor only keeps a zero vector finite.
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _texture_arg(textures, key, channels) -> np.ndarray:
    if not isinstance(textures, dict) or key not in textures:
        raise ValueError(f"skin_maps: textures needs an {key!r} map (keys 'albedo', 'specular', 'normal')")
    tex = np.asarray(textures[key], np.float64)
    if tex.ndim == 2 and channels == 1:
        tex = tex[..., None]
    if tex.ndim != 3 or tex.shape[-1] != channels or tex.shape[0] == 0 or tex.shape[1] == 0:
        raise ValueError(f"skin_maps: textures[{key!r}] must be [H, W, {channels}], got shape {tex.shape}")
    if not np.all(np.isfinite(tex)):
        raise ValueError(f"skin_maps: textures[{key!r}] has NaN or Inf")
    return tex


def _lookup(texture: np.ndarray, uv: np.ndarray, footprint) -> np.ndarray:
    """Texture [H, W, C] at uv [P, 2] (row 0 at v = 1): bilinear (footprint None) or the exact mean over the
    uv rectangle of size footprint = (du, dv) centred on each uv (texels as constant cells)."""
    h, w = texture.shape[:2]
    x, y = uv[:, 0] * w, (1.0 - uv[:, 1]) * h  # continuous texel coordinates, texel centres at k + 1/2
    if footprint is None:
        return _bilinear(texture, x - 0.5, y - 0.5)
    # Summed-area table with a zero row/column in front: sat[j, i] = sum of texels [0:j, 0:i]. It is bilinear in
    # each cell for constant cells, so interpolating it gives the exact integral to any real corner.
    sat = np.zeros((h + 1, w + 1, texture.shape[2]))
    sat[1:, 1:] = np.cumsum(np.cumsum(texture, axis=0), axis=1)
    hx, hy = 0.5 * footprint[0] * w, 0.5 * footprint[1] * h
    x0, x1 = np.clip(x - hx, 0, w), np.clip(x + hx, 0, w)
    y0, y1 = np.clip(y - hy, 0, h), np.clip(y + hy, 0, h)
    area = ((x1 - x0) * (y1 - y0))[:, None]
    total = _bilinear(sat, x1, y1) - _bilinear(sat, x0, y1) - _bilinear(sat, x1, y0) + _bilinear(sat, x0, y0)
    # A footprint entirely outside the texture (uv outside [0, 1]) has no area: take the nearest texel.
    near = _bilinear(texture, np.floor(np.clip(x, 0, w - 1)), np.floor(np.clip(y, 0, h - 1)))
    ok = area > 1e-12
    return np.where(ok, total / np.where(ok, area, 1.0), near)


def _bilinear(grid: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """grid [H, W, C] at continuous indices (x along columns, y along rows; integer = a cell), edges clamped."""
    h, w = grid.shape[:2]
    x, y = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
    x0, y0 = np.minimum(np.floor(x).astype(np.int64), w - 1), np.minimum(np.floor(y).astype(np.int64), h - 1)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = grid[y0, x0] * (1 - fx) + grid[y0, x1] * fx
    bottom = grid[y1, x0] * (1 - fx) + grid[y1, x1] * fx
    return top * (1 - fy) + bottom * fy
