"""Image resampling for previews and pyramids (jax.image underneath)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

__all__ = ["resize_image"]

_METHODS = ("nearest", "linear", "cubic", "lanczos3")


def resize_image(
    image: Float[ArrayLike, "H W C"], size: tuple[int, int], method: str = "linear", antialias: bool = True
) -> Float[Array, "h w C"]:
    """Resize an image with pixel centres aligned: output pixel i samples input position (i + 0.5) H / h - 0.5.

    ``align_corners=False`` in PyTorch terms.

    Args:
        image: the image [H, W, C].
        size: the output (h, w).
        method: the interpolation kernel (``jax.image.resize``'s names, e.g. ``"linear"``).
        antialias: widen the kernel when downsampling (a proper low-pass, needed for previews of maps with a small
            sun); False: plain interpolation, identical to ``torch.nn.functional.interpolate`` /
            ``kornia.geometry.transform.resize`` with ``antialias=False``.

    Returns:
        The image [h, w, C].
    """
    if method not in _METHODS:
        raise ValueError(f"unknown resize method {method!r}; expected one of {_METHODS}")
    img = jnp.asarray(image)
    if img.ndim != 3:
        raise ValueError(f"resize_image needs [H, W, C], got shape {img.shape}")
    h, w = (int(s) for s in size)
    if h <= 0 or w <= 0:
        raise ValueError(f"resize_image: output size must be positive, got {size}")
    return jax.image.resize(img, (h, w, img.shape[2]), method=method, antialias=antialias)
