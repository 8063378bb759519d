"""Camera-view previews of texel-space results: look a texture up through the
mesh's UVs at each primary-ray hit."""

from __future__ import annotations

import numpy as np

import stage

# Sub-pixel rays per band of a camera-view image (``texture_view``; ``relight.render.render_view``): a few hundred
# bytes a ray, so tens of MiB a band, whatever the image size.
BAND_RAYS = 1 << 18


def row_bands(camera: stage.Camera, supersample: int):
    """The bands of rows a camera-view image is worked in, each of at most ``BAND_RAYS`` sub-pixel rays.

    Args:
        camera: the image's camera.
        supersample: sub-pixels per pixel side.

    Yields:
        ``(first row, band camera)``: the band's ``Camera.crop`` (all columns, consecutive rows); one band
        holding the whole image when it has at most ``BAND_RAYS`` sub-pixels.
    """
    rows = max(1, BAND_RAYS // (camera.width * supersample * supersample))
    for r0 in range(0, camera.height, rows):
        yield r0, camera.crop(0, r0, camera.width, min(rows, camera.height - r0))


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear lookup of a texture at uv coordinates (row 0 at v = 1).

    Args:
        texture: the texture [H, W, C].
        uv: coordinates [..., 2].

    Returns:
        Values [..., C].
    """
    h, w = texture.shape[:2]
    x = np.clip(uv[..., 0] * w - 0.5, 0, w - 1)
    y = np.clip((1 - uv[..., 1]) * h - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[..., None], (y - y0)[..., None]
    top = texture[y0, x0] * (1 - fx) + texture[y0, x1] * fx
    bot = texture[y1, x0] * (1 - fx) + texture[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def texture_view(mesh: stage.Mesh, camera: stage.Camera, textures: dict[str, np.ndarray], supersample: int = 2,
                 background: float = 0.0) -> dict[str, np.ndarray]:
    """Each texture as the camera sees the mesh, box-filtered from ``supersample``^2 rays per pixel (anti-aliasing).

    Args:
        mesh: the mesh (with UVs).
        camera: the camera.
        textures: ``name -> texture`` [H, W, C].
        supersample: rays per pixel along each axis.
        background: the value where no ray hits the mesh.

    Returns:
        ``name -> image`` [h, w, C] at the camera's resolution.
    """
    s = int(supersample)
    occ = stage.Occluder(mesh)
    out = {name: np.empty((camera.height, camera.width, tex.shape[-1]), np.float32) for name, tex in textures.items()}
    for r0, band in row_bands(camera, s):  # the rays' arrays stay one band's
        hit, face, bary, _ = stage.primary_hits(mesh, band, s, occluder=occ)
        uv = np.einsum("hwk,hwkc->hwc", bary, mesh.uv[mesh.faces[np.maximum(face, 0)]])
        for name, tex in textures.items():
            img = np.where(hit[..., None], sample_texture(tex, uv), background)
            out[name][r0:r0 + band.height] = img.reshape(band.height, s, band.width, s, -1).mean(axis=(1, 3))
    return out


def dilate(texture: np.ndarray, valid: np.ndarray, iterations: int = 2) -> np.ndarray:
    """Fill texels outside the UV charts with the mean of their valid 4-neighbours, ``iterations`` times.

    So bilinear lookups at chart borders do not blend in the empty background (the usual texture-bake padding).

    Args:
        texture: the texture [H, W, C].
        valid: the texels inside the charts, bool [H, W].
        iterations: rings of texels filled.

    Returns:
        The padded texture [H, W, C].
    """
    tex = np.array(texture, dtype=np.float32, copy=True)
    ok = np.array(valid, dtype=bool, copy=True)
    for _ in range(iterations):
        acc = np.zeros_like(tex)
        cnt = np.zeros(ok.shape, np.float32)
        for dy, dx in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            sh_ok = np.roll(ok, (dy, dx), axis=(0, 1))
            acc += np.where(sh_ok[..., None], np.roll(tex, (dy, dx), axis=(0, 1)), 0)
            cnt += sh_ok
        grow = ~ok & (cnt > 0)
        tex[grow] = acc[grow] / cnt[grow][:, None]
        ok |= grow
    return tex


# Texel-space previews (one pixel a texel) are enlarged to at least this many pixels a side: a 48 x 48 grid
# is a stamp on screen. Nearest neighbour, by a whole factor, so each texel stays a visible square.
PREVIEW_MIN_PX = 256


def upscale_nearest(img: np.ndarray, min_px: int = PREVIEW_MIN_PX) -> np.ndarray:
    """An image repeated k times along H and W, k the smallest whole factor giving a shorter side >= ``min_px``.

    Args:
        img: the image [H, W, ...].
        min_px: the smallest shorter side wanted.

    Returns:
        The image [k H, k W, ...] (k = 1: unchanged).
    """
    img = np.asarray(img)
    k = max(1, -(-int(min_px) // max(1, min(img.shape[:2]))))
    return img if k == 1 else np.repeat(np.repeat(img, k, axis=0), k, axis=1)
