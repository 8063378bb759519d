"""Texture-space diffusion with separable Gaussian blurs (d'Eon, Luebke &
Enderton 2007, "Efficient Rendering of Human Skin", section 4; GPU Gems 3
ch. 14): irradiance is laid out in the texture atlas, blurred once per Gaussian
of a ``SumOfGaussians`` profile, and the blurs are summed with the per-channel
weights.

Contract:

    tsd = TextureSpaceDiffusion.build(texel_index [P, 2] (row, col), (H, W), positions [P, 3] mm)
    exitance [P, C] = tsd.apply(sum_of_gaussians, irradiance [P, C])

Kernel widths are in mm on the surface; ``build`` measures the texture stretch
(mm per texel along rows and columns) from the 3-D positions of neighbouring
texels, and each blur uses sigma_texels = sigma_mm / stretch at the texel being
written (d'Eon's stretch-corrected blur). Successive Gaussians are obtained
incrementally (blur the previous result by the variance difference), which is
exact for Gaussians on a flat, uniformly parametrised chart.

Empty texels (outside the charts) are handled by normalised convolution: the
blur of (mask x irradiance) is divided by the blur of the mask, so uniform
irradiance in gives exactly sum_k w_k times it out (energy conserving), and no
black gutter bleeds in. Light does not cross UV seams (texels across a seam are
not texture neighbours): that, and the stretch approximation, are the errors
against the 3-D ``DiffusionOperator``.

``gaussian_blur`` is the plain separable blur with reflect borders (kornia's
``gaussian_blur2d`` semantics), the building block checked against kornia.
"""

from __future__ import annotations

import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from brdf import safe_div

from ._common import concrete
from ._gaussians import SumOfGaussians

# Kernels reach truncate x sigma on each side (kornia users typically take
# kernel_size = 2 ceil(3 sigma) + 1: the Gaussian beyond 3 sigma holds 0.27 % of it).
TRUNCATE = 3.0
# Blur widths below this (texels) are the identity: the kernel is a delta to
# float32 precision (exp(-1/(2 * 0.2^2)) ~ 4e-6).
_SIGMA_MIN_TEXELS = 0.2


def gaussian_kernel1d(sigma: float, truncate: float = TRUNCATE, dtype=None) -> Float[Array, " taps"]:
    """A normalised 1-D Gaussian kernel of standard deviation ``sigma`` (texels), 2 ceil(truncate sigma) + 1 taps.

    The same discrete kernel as kornia's ``get_gaussian_kernel1d``.

    Args:
        sigma: standard deviation in texels (concrete).
        truncate: half-width in standard deviations.
        dtype: the kernel's dtype (None: the default float).

    Returns:
        The taps [2 ceil(truncate sigma) + 1], summing to 1.
    """
    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"gaussian_kernel1d: sigma (texels) must be finite and > 0, got {sigma!r}")
    half = int(math.ceil(truncate * sigma))
    x = np.arange(-half, half + 1, dtype=np.float64)
    k = np.exp(-(x**2) / (2 * sigma**2))
    return jnp.asarray(k / k.sum(), dtype or jnp.result_type(float))


def gaussian_blur(
    image: Float[Array, "height width channel"], sigma: float, truncate: float = TRUNCATE
) -> Float[Array, "height width channel"]:
    """Separable Gaussian blur of an image with a reflect border (no edge repeat).

    Args:
        image: the image [H, W, C].
        sigma: standard deviation in texels (a concrete float).
        truncate: half-width of the kernel in standard deviations (2 ceil(truncate sigma) + 1 taps).

    Returns:
        The blurred image [H, W, C].
    """
    image = jnp.asarray(image)
    if image.ndim != 3:
        raise ValueError(f"gaussian_blur: image must have shape [H, W, C], got {image.shape}")
    k = gaussian_kernel1d(float(sigma), truncate, image.dtype)
    half = (k.shape[0] - 1) // 2
    H, W, _ = image.shape
    if half >= min(H, W):
        raise ValueError(f"gaussian_blur: kernel half-width {half} must be < image size {min(H, W)} (reflect border)")
    out = _conv_axis(jnp.pad(image, ((half, half), (0, 0), (0, 0)), mode="reflect"), k, axis=0)
    return _conv_axis(jnp.pad(out, ((0, 0), (half, half), (0, 0)), mode="reflect"), k, axis=1)


def _conv_axis(padded, k, axis):
    """Valid 1-D correlation of ``padded`` with ``k`` along ``axis`` (0 or 1), per channel."""
    x = jnp.moveaxis(padded, -1, 0)[:, None]  # [C, 1, H', W']
    kern = k.reshape((1, 1, -1, 1) if axis == 0 else (1, 1, 1, -1))
    y = jax.lax.conv_general_dilated(x, kern, (1, 1), "VALID", precision=jax.lax.Precision.HIGHEST)
    return jnp.moveaxis(y[:, 0], 0, -1)


def _blur_variable(num, den, sigma, half, axis):
    """Normalised-convolution blur along ``axis`` with a per-texel sigma (texels) [H, W]:
    sum_k g_k(x) f(x + k), g_k(x) = exp(-k^2 / (2 sigma(x)^2)), applied to the
    numerator [H, W, C] and denominator [H, W] alike (zero outside the image)."""
    if half == 0:
        return num, den
    pad = [(0, 0)] * 3
    pad[axis] = (half, half)
    num_p = jnp.pad(num, pad)
    den_p = jnp.pad(den, pad[:2])
    size = num.shape[axis]
    s = jnp.maximum(sigma, _SIGMA_MIN_TEXELS)

    def step(acc, k):
        an, ad = acc
        kf = k.astype(s.dtype)
        g = jnp.where(jnp.abs(kf) <= jnp.ceil(TRUNCATE * s), jnp.exp(-(kf**2) / (2 * s * s)), 0)
        sn = jax.lax.dynamic_slice_in_dim(num_p, k + half, size, axis)
        sd = jax.lax.dynamic_slice_in_dim(den_p, k + half, size, axis)
        return (an + g[..., None] * sn, ad + g * sd), None

    (n, d), _ = jax.lax.scan(step, (jnp.zeros_like(num), jnp.zeros_like(den)), jnp.arange(-half, half + 1))
    return n, d


@functools.partial(jax.jit, static_argnames="halves")
def _blurs(rows, cols, mask, stretch, dv, E, *, halves):
    H, W = mask.shape
    num = jnp.zeros((H, W, E.shape[1]), E.dtype).at[rows, cols].set(E)
    den = mask.astype(E.dtype)

    def gaussian(carry, dvk):
        num, den = carry
        for axis in (0, 1):
            sigma = jnp.sqrt(dvk) / stretch[..., axis]
            num, den = _blur_variable(num, den, sigma, halves[axis], axis)
        return (num, den), safe_div(num, den[..., None])[rows, cols]

    _, out = jax.lax.scan(gaussian, (num, den), dv)
    return out


class TextureSpaceDiffusion(eqx.Module):
    """Texture-space sum-of-Gaussians diffusion (see the module docstring).

    ``rows``, ``cols`` [P] texel of each sample; ``mask`` [H, W] texels that hold a
    sample; ``stretch`` [H, W, 2] mm per texel along rows (v) and columns (u);
    static ``min_stretch`` (its smallest value per axis, which sets the tap count).
    """

    rows: Int[Array, " sample"]
    cols: Int[Array, " sample"]
    mask: Bool[Array, "height width"]
    stretch: Float[Array, "height width 2"]
    min_stretch: tuple[float, float] = eqx.field(static=True)

    @classmethod
    def build(
        cls,
        texel_index: Int[ArrayLike, "sample 2"] | Int[ArrayLike, " sample"],
        resolution: tuple[int, int],
        positions: Float[ArrayLike, "sample 3"],
        dtype=None,
    ) -> TextureSpaceDiffusion:
        """Texel layout and stretch from the samples' texels and 3-D positions (mm).

        ``texel_index`` is [P, 2] (row, col) or [P] row-major flat indices (``stage.Surface.texel_index``).

        Stretch along an axis is the 3-D distance to the adjacent texel on that axis,
        the smaller of the two sides where both exist (a neighbour across a UV seam is
        far in 3-D; the smaller side avoids it); texels with no neighbour on an axis
        take the median stretch of that axis.
        """
        ti = np.asarray(texel_index)
        pos = np.asarray(positions, np.float64)
        H, W = (int(resolution[0]), int(resolution[1]))
        if ti.ndim == 1 and np.issubdtype(ti.dtype, np.integer):
            ti = np.stack([ti // W, ti % W], axis=1)
        P = ti.shape[0] if ti.ndim == 2 else -1
        if ti.ndim != 2 or ti.shape[1] != 2 or not np.issubdtype(ti.dtype, np.integer):
            raise ValueError(
                f"TextureSpaceDiffusion.build: texel_index must be integer [P, 2] (row, col), got {ti.dtype} {ti.shape}"
            )
        if pos.shape != (P, 3) or not np.all(np.isfinite(pos)):
            raise ValueError(f"TextureSpaceDiffusion.build: positions must be finite [P={P}, 3] (mm), got {pos.shape}")
        if H < 1 or W < 1 or np.any(ti < 0) or np.any(ti[:, 0] >= H) or np.any(ti[:, 1] >= W):
            raise ValueError(f"TextureSpaceDiffusion.build: texel_index out of the {H}x{W} texture")
        flat = ti[:, 0] * W + ti[:, 1]
        if np.unique(flat).size != P:
            raise ValueError("TextureSpaceDiffusion.build: two samples share a texel (texel_index must be unique)")
        mask = np.zeros((H, W), bool)
        mask[ti[:, 0], ti[:, 1]] = True
        img = np.zeros((H, W, 3))
        img[ti[:, 0], ti[:, 1]] = pos
        stretch = np.empty((H, W, 2))
        for axis in (0, 1):
            fwd = np.full((H, W), np.inf)
            sl_a = [slice(None)] * 2
            sl_b = [slice(None)] * 2
            sl_a[axis], sl_b[axis] = slice(0, -1), slice(1, None)
            sa, sb = tuple(sl_a), tuple(sl_b)
            both = mask[sa] & mask[sb]
            d = np.where(both, np.linalg.norm(img[sb] - img[sa], axis=-1), np.inf)
            fwd[sa] = d  # distance to the next texel
            bwd = np.full((H, W), np.inf)
            bwd[sb] = d  # distance to the previous texel
            st = np.minimum(fwd, bwd)
            finite = mask & np.isfinite(st) & (st > 0)
            med = float(np.median(st[finite])) if finite.any() else 1.0
            stretch[..., axis] = np.where(finite, st, med)
        dtype = dtype or jnp.result_type(float)
        return cls(
            rows=jnp.asarray(ti[:, 0], jnp.int32),
            cols=jnp.asarray(ti[:, 1], jnp.int32),
            mask=jnp.asarray(mask),
            stretch=jnp.asarray(stretch, dtype),
            min_stretch=(float(stretch[..., 0][mask].min()), float(stretch[..., 1][mask].min())),
        )

    def blurs(
        self,
        variances_mm2: Float[ArrayLike, " gaussian"],
        irradiance: Float[Array, "sample channel"],
        max_variance_mm2: float | None = None,
    ) -> Float[Array, "gaussian sample channel"]:
        """Irradiance blurred by each Gaussian (variances in mm^2, increasing), normalised so
        each blur of a uniform irradiance is that irradiance, [K, P, C].

        The number of taps is static: it comes from the variances when they are concrete
        (close over the profile under ``jit``), else from ``max_variance_mm2``, an upper
        bound on the largest variance. Differentiable in the irradiance (and the weights in
        ``apply``); the kernel widths are not differentiated through the tap count.
        """
        v = jnp.asarray(variances_mm2)
        vc = concrete(v)
        if vc is not None:
            if vc.ndim != 1 or vc.size == 0 or np.any(vc <= 0) or np.any(np.diff(vc) < 0):
                raise ValueError(f"TextureSpaceDiffusion.blurs: variances must be positive and increasing, got {vc!r}")
            widest = float(np.max(np.diff(np.concatenate([[0.0], vc]))))
        elif max_variance_mm2 is not None:
            widest = float(max_variance_mm2)
        else:
            raise ValueError(
                "TextureSpaceDiffusion.blurs: variances are traced; close over the profile or pass max_variance_mm2"
            )
        E = jnp.asarray(irradiance)
        H, W = self.mask.shape
        P = self.rows.shape[0]
        if E.ndim != 2 or E.shape[0] != P:
            raise ValueError(f"TextureSpaceDiffusion: irradiance must have shape [P={P}, C], got {E.shape}")
        dv = jnp.diff(jnp.concatenate([jnp.zeros(1, v.dtype), v])).astype(E.dtype)
        # one tap count per axis for every pass (static, so one compiled pass per axis):
        # the widest increment over the smallest stretch; taps beyond 3 sigma weigh 0
        halves = tuple(
            min(int(math.ceil(TRUNCATE * math.sqrt(widest) / self.min_stretch[a])), (H, W)[a] - 1) for a in (0, 1)
        )
        return _blurs(self.rows, self.cols, self.mask, self.stretch.astype(E.dtype), dv, E, halves=halves)

    def apply(
        self,
        profile: SumOfGaussians,
        irradiance: Float[Array, "sample channel"],
        max_variance_mm2: float | None = None,
    ) -> Float[Array, "sample channel"]:
        """Exitance sum_k w_k blur_k(E) at every sample, [P, C]; ``profile`` weights [K, C]
        or per sample [P, K, C] (variances sorted increasing, as in d'Eon et al. 2007).
        ``max_variance_mm2``: see ``blurs`` (needed only when the variances are traced)."""
        if not isinstance(profile, SumOfGaussians):
            got = type(profile).__name__
            raise ValueError(f"TextureSpaceDiffusion.apply: profile must be a SumOfGaussians, got {got}")
        b = self.blurs(profile.variances, irradiance, max_variance_mm2)  # [K, P, C]
        w = profile.weights
        if w.ndim == 2:
            return jnp.einsum("kc,kpc->pc", w, b)
        if w.ndim == 3 and w.shape[0] == b.shape[1]:
            return jnp.einsum("pkc,kpc->pc", w, b)
        raise ValueError(f"TextureSpaceDiffusion.apply: weights must be [K, C] or [P, K, C], got {w.shape}")
