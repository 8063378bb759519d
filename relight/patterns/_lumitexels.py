"""Lumitexels: one surface sample's response to every light of a rig, as one
camera sees it (Kang et al. 2018, sec. 3: the input of the autoencoder).

For light l the lumitexel holds the OLAT radiance of ``stage``'s one forward
model (``stage.incident_light``, ``stage.to_local``,
``stage.reflected_radiance_lights``; pbrt-v4 eq. 4.14 with a delta light):

    m[l, c] = f_r(wi_l, wo) max(cos theta_i, 0) E_l,c(p) V_l

for a Lambert + GGX material (``brdf.lambert_ggx``: rho_d, Schlick F0 =
rho_s, isotropic alpha; the ladder's Lambert .. GGX rungs), a sample position
p in the stage volume, a shading normal facing the camera and the light
visibility V (the hemisphere cut always; optionally a random occluding cap).
``white`` is the same for a white Lambertian (f_r = 1/pi): what the geometry
alone delivers, the decoder's normaliser.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

import brdf
import stage
from brdf import safe_normalize


class ParameterRanges(eqx.Module):
    """Where random materials and geometry are drawn from (every value a float).

    rho_d: diffuse albedo per channel, uniform in [lo, hi]; rho_s: Schlick F0,
    uniform in [lo, hi], and 0 (a Lambert sample) with probability
    ``lambert_fraction``; alpha: GGX roughness, log-uniform in [lo, hi];
    ``radius_mm``: sample positions uniform in a ball of that radius about the
    rig centre (a head-sized region); ``max_view_deg``: the shading normal
    uniform on the cap of that half-angle about the view direction;
    ``occlusion``: probability that a sample has one occluding cap (a random
    direction in its upper hemisphere, half-angle ``occluder_deg``) that
    shadows the lights behind it (self-shadowing of a face: nose, brow)."""

    rho_d: tuple[float, float] = eqx.field(static=True, default=(0.02, 0.95))
    rho_s: tuple[float, float] = eqx.field(static=True, default=(0.0, 0.12))
    lambert_fraction: float = eqx.field(static=True, default=0.1)
    alpha: tuple[float, float] = eqx.field(static=True, default=(0.05, 0.8))
    radius_mm: float = eqx.field(static=True, default=100.0)
    max_view_deg: float = eqx.field(static=True, default=75.0)
    occlusion: float = eqx.field(static=True, default=0.0)
    occluder_deg: tuple[float, float] = eqx.field(static=True, default=(15.0, 40.0))

    def __check_init__(self):
        for name in ("rho_d", "rho_s", "alpha", "occluder_deg"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
                raise ValueError(f"ParameterRanges.{name} must be 0 <= lo <= hi, got {(lo, hi)}")
        if self.rho_d[1] > 1 or self.rho_s[1] > 1 or self.alpha[0] <= 0 or self.alpha[1] > 1:
            raise ValueError("ParameterRanges: albedos must lie in [0, 1] and alpha in (0, 1]")
        if not (0 <= self.lambert_fraction <= 1 and 0 <= self.occlusion <= 1):
            raise ValueError("ParameterRanges: lambert_fraction and occlusion are probabilities in [0, 1]")
        if not (0 < self.max_view_deg < 90 and self.radius_mm >= 0):
            raise ValueError("ParameterRanges: max_view_deg must be in (0, 90) and radius_mm >= 0")


# The training ranges (the defaults of ParameterRanges).
TRAIN_RANGES = ParameterRanges()
# The held-out test set of docs/patterns.md: narrower than training (every
# sample has a lobe, alpha above the Light Stage X's floor ~0.07).
TEST_RANGES = ParameterRanges(rho_d=(0.1, 0.8), rho_s=(0.02, 0.08), lambert_fraction=0.0, alpha=(0.1, 0.6))


class Lumitexels(eqx.Module):
    """N samples' lumitexels and what made them: ``radiance`` [N, L, C] (OLAT
    radiance toward the camera, the rig's intensity units per sr), ``white``
    [N, L, C] (the same for a white Lambertian, f_r = 1/pi), ``visible``
    [N, L] (lit: above the horizon and not occluded), the material
    ``rho_d`` [N, 3], ``rho_s`` [N] (F0), ``alpha`` [N], and the geometry:
    ``position`` [N, 3] mm, the shading frame ``normal`` / ``tangent`` /
    ``bitangent`` [N, 3] and the unit view direction ``wo`` [N, 3] (world,
    toward the camera)."""

    radiance: Float[Array, "sample light channel"]
    white: Float[Array, "sample light channel"]
    visible: Bool[Array, "sample light"]
    rho_d: Float[Array, "sample 3"]
    rho_s: Float[Array, " sample"]
    alpha: Float[Array, " sample"]
    position: Float[Array, "sample 3"]
    normal: Float[Array, "sample 3"]
    tangent: Float[Array, "sample 3"]
    bitangent: Float[Array, "sample 3"]
    wo: Float[Array, "sample 3"]

    @property
    def num_samples(self) -> int:
        return self.radiance.shape[0]

    def geometry(self) -> Float[Array, "sample 9"]:
        """The decoder's geometric input: normal, view direction, position / 200 mm."""
        return geometry_features(self.normal, self.wo, self.position)


def geometry_features(normal, wo, position) -> Float[Array, "sample 9"]:
    """What the light stage knows of each sample from the scanned mesh: [n, wo, p / 200 mm].

    Args:
        normal: unit normals [P, 3].
        wo: unit directions toward the camera [P, 3].
        position: positions (mm) [P, 3].

    Returns:
        Features [P, 9].
    """
    p = jnp.asarray(position)
    return jnp.concatenate([jnp.asarray(normal, p.dtype), jnp.asarray(wo, p.dtype), p / 200.0], axis=-1)


def _cap(key, axis, max_deg, n):
    """n unit vectors uniform on the spherical cap of half-angle ``max_deg`` about ``axis`` [n, 3]."""
    k1, k2 = jax.random.split(key)
    dt = axis.dtype
    cos_max = jnp.cos(jnp.deg2rad(jnp.asarray(max_deg, dt)))
    z = 1.0 - jax.random.uniform(k1, (n,), dt) * (1.0 - cos_max)
    phi = 2.0 * jnp.pi * jax.random.uniform(k2, (n,), dt)
    r = jnp.sqrt(jnp.maximum(1.0 - z * z, 0.0))
    t, b = brdf.orthonormal_basis(axis)
    return safe_normalize(t * (r * jnp.cos(phi))[:, None] + b * (r * jnp.sin(phi))[:, None] + axis * z[:, None])


def sample_materials(key, n: int, ranges: ParameterRanges = TRAIN_RANGES, dtype=jnp.float32):
    """Random Lambert + GGX materials drawn from ``ranges`` (see ``ParameterRanges``).

    Args:
        key: a ``jax.random`` key.
        n: the number of samples.
        ranges: the parameter ranges.
        dtype: the float dtype.

    Returns:
        (rho_d [n, 3], rho_s [n], alpha [n]).
    """
    k1, k2, k3, k4 = jax.random.split(key, 4)
    u = lambda k, shape, lo, hi: lo + (hi - lo) * jax.random.uniform(k, shape, dtype)  # noqa: E731
    rho_d = u(k1, (n, 3), *ranges.rho_d)
    rho_s = u(k2, (n,), *ranges.rho_s) * (jax.random.uniform(k3, (n,), dtype) >= ranges.lambert_fraction).astype(dtype)
    alpha = jnp.exp(u(k4, (n,), float(np.log(ranges.alpha[0])), float(np.log(ranges.alpha[1]))))
    return rho_d, rho_s, alpha


def sample_geometry(key, n: int, camera_center, ranges: ParameterRanges = TRAIN_RANGES, dtype=jnp.float32):
    """Random sample geometry: positions uniform in a ball, normals uniform on a cap about the view direction.

    Args:
        key: a ``jax.random`` key.
        n: the number of samples.
        camera_center: the camera's position (mm) [3]; the view directions point toward it.
        ranges: ``radius_mm`` (the ball) and ``max_view_deg`` (the cap about wo).
        dtype: the float dtype.

    Returns:
        (position [n, 3] mm, normal [n, 3], wo [n, 3]).
    """
    k1, k2, k3 = jax.random.split(key, 3)
    d = safe_normalize(jax.random.normal(k1, (n, 3), dtype))
    r = ranges.radius_mm * jax.random.uniform(k2, (n, 1), dtype) ** (1.0 / 3.0)
    position = d * r
    wo = safe_normalize(jnp.asarray(camera_center, dtype)[None] - position)
    normal = _cap(k3, wo, ranges.max_view_deg, n)
    return position, normal, wo


def _local_lighting(rig: stage.Rig, position, normal, tangent, bitangent, wo):
    """(wi [L, N, 3], wo [N, 3] in each sample's local frame, irradiance [L, N, C]) of every light at
    every sample, in the dtype of ``position``: stage's ``incident_light`` and ``to_local``."""
    dt = jnp.asarray(position).dtype
    c = lambda x: jnp.asarray(x, dt)  # noqa: E731
    wi_world, irr = stage.incident_light(c(rig.position), c(rig.intensity), rig.near_field, c(position))
    t, b, n = c(tangent), c(bitangent), c(normal)
    return stage.to_local(wi_world, t, b, n), stage.to_local(c(wo), t, b, n), irr


def lumitexels(rig: stage.Rig, position, normal, tangent, bitangent, wo, rho_d, rho_s, alpha,
               visible=None) -> tuple[Array, Array, Array]:
    """Lumitexels of Lambert + GGX samples through stage's forward model (module docstring).

    Args:
        rig: the light rig.
        position, normal, tangent, bitangent: each sample's position (mm) and frame, [N, 3].
        wo: unit directions toward the camera, [N, 3].
        rho_d, rho_s, alpha: the materials, [N, 3], [N], [N].
        visible: the light visibility (shadowing) [N, L], combined with the horizon (None: no shadowing).

    Returns:
        (radiance [N, L, C], white [N, L, C], lit [N, L]).

    References:
        Kang et al. 2018, "Efficient reflectance capture using an autoencoder".
    """
    dt = jnp.asarray(position).dtype
    c = lambda x: jnp.asarray(x, dt)  # noqa: E731
    wi, wo_l, irr = _local_lighting(rig, position, normal, tangent, bitangent, wo)
    lit = wi[..., 2] > 0
    if visible is not None:
        lit = lit & jnp.asarray(visible).T
    mat = brdf.lambert_ggx(c(rho_d), c(rho_s)[:, None], c(alpha)[:, None])
    rad = stage.reflected_radiance_lights(mat, wi, wo_l, irr, lit)
    white = stage.reflected_radiance_lights(brdf.Lambert(jnp.ones_like(c(rho_d))), wi, wo_l, irr, lit)
    return jnp.swapaxes(rad, 0, 1), jnp.swapaxes(white, 0, 1), lit.T


# Roughnesses of the decoder's closed-form specular bases (``specular_bases``):
# log-spaced over the ladder's range, from the Light Stage X's floor (~0.07) up.
ALPHA_GRID = (0.08, 0.14, 0.25, 0.45, 0.8)


def specular_bases(rig: stage.Rig, position, normal, tangent, bitangent, wo, lit,
                   alphas=ALPHA_GRID) -> Float[Array, "sample light channel basis"]:
    """The GGX lobe's lumitexels at the roughnesses ``alphas``, split by Schlick's Fresnel being affine in F0.

    F = F0 (1 - s) + s with s = (1 - cos)^5: basis 2j = lobe(F0 = 1) - lobe(F0 = 0) (the F0 coefficient), basis
    2j + 1 = lobe(F0 = 0) (the offset). So a Lambert + GGX(alpha_j) lumitexel is exactly
    rho_d white + F0 basis_2j + basis_2j+1.

    Args:
        rig: the light rig.
        position, normal, tangent, bitangent: each sample's position (mm) and frame, [N, 3].
        wo: unit directions toward the camera, [N, 3].
        lit: the light visibility [N, L].
        alphas: the J roughnesses.

    Returns:
        Bases [N, L, C, 2J] (C = the rig's channels).
    """
    dt = jnp.asarray(position).dtype
    wi, wo_l, irr = _local_lighting(rig, position, normal, tangent, bitangent, wo)
    vis = jnp.asarray(lit).T & (wi[..., 2] > 0)
    N = wo_l.shape[0]
    out = []
    for a in alphas:
        al = jnp.full((N, 1), a, dt)
        lobe = lambda f0, al=al: stage.reflected_radiance_lights(  # noqa: E731
            brdf.Microfacet(brdf.GGX(al), brdf.SchlickFresnel(jnp.full((N, 1), f0, dt)), "smith"), wi, wo_l, irr, vis)
        zero = lobe(0.0)
        out += [lobe(1.0) - zero, zero]
    return jnp.stack([jnp.swapaxes(x, 0, 1) for x in out], axis=-1)


def _occluders(key, n, normal, lights_dir, ranges: ParameterRanges):
    """[n, L] bool: True where a light is NOT behind the sample's random occluding cap."""
    k1, k2, k3 = jax.random.split(key, 3)
    dt = normal.dtype
    axis = _cap(k1, normal, 80.0, n)
    lo, hi = ranges.occluder_deg
    half = jnp.deg2rad(lo + (hi - lo) * jax.random.uniform(k2, (n,), dt))
    has = jax.random.uniform(k3, (n,), dt) < ranges.occlusion
    blocked = jnp.einsum("nd,lnd->nl", axis, lights_dir) > jnp.cos(half)[:, None]
    return ~(blocked & has[:, None])


def simulate_lumitexels(key, rig: stage.Rig, camera_center, n: int, ranges: ParameterRanges = TRAIN_RANGES,
                        dtype=jnp.float32) -> Lumitexels:
    """n random samples (materials and geometry from ``ranges``) and their lumitexels under ``rig``.

    Pure JAX: jit it with ``n`` and ``ranges`` static for training.

    Args:
        key: a ``jax.random`` key.
        rig: the light rig.
        camera_center: the camera's position (mm) [3].
        n: the number of samples.
        ranges: the parameter ranges.
        dtype: the float dtype.

    Returns:
        The ``Lumitexels``.

    References:
        Kang et al. 2018, "Efficient reflectance capture using an autoencoder".
    """
    km, kg, ko = jax.random.split(key, 3)
    rho_d, rho_s, alpha = sample_materials(km, n, ranges, dtype)
    position, normal, wo = sample_geometry(kg, n, camera_center, ranges, dtype)
    t, b = brdf.orthonormal_basis(normal)
    visible = None
    if ranges.occlusion > 0:
        wi_world, _ = stage.incident_light(jnp.asarray(rig.position, dtype), jnp.asarray(rig.intensity, dtype),
                                           rig.near_field, position)
        visible = _occluders(ko, n, normal, wi_world, ranges)
    rad, white, lit = lumitexels(rig, position, normal, t, b, wo, rho_d, rho_s, alpha, visible)
    return Lumitexels(radiance=rad, white=white, visible=lit, rho_d=rho_d, rho_s=rho_s, alpha=alpha,
                      position=position, normal=normal, tangent=t, bitangent=b, wo=wo)


def as_surface(lumi: Lumitexels) -> stage.Surface:
    """The samples as a ``stage.Surface`` of independent texels (for ``stage.simulate``, ``stage.simulate_patterns``).

    Args:
        lumi: the lumitexels.

    Returns:
        The ``Surface``.
    """
    P = lumi.num_samples
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    return stage.Surface(position=f(lumi.position), normal=f(lumi.normal), tangent=f(lumi.tangent),
                         bitangent=f(lumi.bitangent), uv=jnp.zeros((P, 2), jnp.float32),
                         area=jnp.ones((P,), jnp.float32), texel_index=jnp.arange(P, dtype=jnp.int32),
                         face=jnp.zeros((P,), jnp.int32), resolution=(1, P))


def as_capture(lumi: Lumitexels, rig: stage.Rig, camera: stage.Camera) -> stage.Capture:
    """The lumitexels as a one-view OLAT ``stage.Capture`` [1, L, N, C], masked where lit and front-facing.

    Args:
        lumi: the lumitexels.
        rig: the light rig.
        camera: the camera they were seen from.

    Returns:
        The ``Capture``.
    """
    rad = jnp.swapaxes(jnp.asarray(lumi.radiance, jnp.float32), 0, 1)[None]
    return stage.Capture(radiance=rad, mask=jnp.swapaxes(lumi.visible, 0, 1)[None], rig=rig, cameras=(camera,))
