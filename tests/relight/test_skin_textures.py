"""The head scan's bundled skin textures and the ground-truth skin material
built from them: decoding (sRGB closed form, 16-bit round trips, unit normals),
the texture orientation proved on the face (lips, eyebrows), the normal map's
green-channel convention, exact box filtering, the normal perturbation, the
region-varying mean free path, and the refusals."""

import hashlib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy.ndimage import gaussian_filter

import relight.materials as M
import skin_bssrdf
import stage
from relight.io import HEAD_SKIN_FILES, ImageFormatError, head_skin_textures, read_texture, write_png
from tests.helpers import assert_finite

SHARED_NAMES = {"albedo": "Map-COL.jpg", "specular": "Map-SPEC.jpg",
                "normal": "Infinite-Level_02_Tangent_SmoothUV.jpg"}
RES = 128  # texel grid for the material tests: 15k samples, ~1 mm texels on the face


def _srgb_decode_reference(v):
    """IEC 61966-2-1, written out independently of relight.image.srgb_decode."""
    v = np.asarray(v, np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _bundled(key):
    return Path(str(resources.files("relight.data").joinpath(HEAD_SKIN_FILES[key])))


@pytest.fixture(scope="module")
def head():
    return stage.load_head()


@pytest.fixture(scope="module")
def textures():
    return head_skin_textures()


@pytest.fixture(scope="module")
def surface(head):
    return stage.texel_samples(head, RES)


@pytest.fixture(scope="module")
def truth(surface, textures):
    return M.skin_maps(surface, textures)


# --- decoding ---------------------------------------------------------------------------------------------------

def test_srgb_decode_matches_closed_form(tmp_path):
    codes = np.array([0, 1, 10, 11, 64, 128, 200, 255], np.uint8)  # 10/255 < 0.04045 < 11/255: both branches
    img = np.stack([codes, codes[::-1], codes], axis=-1)[None]  # [1, 8, 3]
    write_png(tmp_path / "codes.png", img)
    lin = read_texture(tmp_path / "codes.png")
    assert lin.dtype == np.float32 and lin.shape == (1, 8, 3)
    np.testing.assert_allclose(lin, _srgb_decode_reference(img / 255.0), rtol=1e-6, atol=1e-7)
    assert lin[0, 5, 0] == pytest.approx(0.2158605, abs=1e-6)  # 128 -> 0.2158605 (the standard's table value)
    np.testing.assert_allclose(read_texture(tmp_path / "codes.png", srgb=False), img / 255.0, atol=1e-7)


def test_png_16bit_round_trip_keeps_16_bits_and_alpha(tmp_path):
    rng = np.random.default_rng(3)
    img = rng.integers(0, 65536, (5, 7, 4), dtype=np.uint16)
    img[0, 0] = [1, 2, 3, 65535]  # values a reduction to 8 bits would destroy
    write_png(tmp_path / "rgba16.png", img)
    raw = read_texture(tmp_path / "rgba16.png", srgb=False)
    np.testing.assert_allclose(raw, img / 65535.0, rtol=1e-6, atol=1e-9)
    lin = read_texture(tmp_path / "rgba16.png")
    np.testing.assert_allclose(lin[..., :3], _srgb_decode_reference(img[..., :3] / 65535.0), rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(lin[..., 3], img[..., 3] / 65535.0, rtol=1e-6)  # alpha is never decoded


def test_tiff_16bit_and_jpeg_through_pillow(tmp_path):
    grey = (np.arange(12, dtype=np.uint16).reshape(3, 4) * 5000 + 7)
    Image.fromarray(grey).save(tmp_path / "grey16.tif")
    out = read_texture(tmp_path / "grey16.tif", srgb=False)
    assert out.shape == (3, 4, 1)
    np.testing.assert_allclose(out[..., 0], grey / 65535.0, rtol=1e-6)
    Image.fromarray(np.full((16, 16, 3), [200, 100, 30], np.uint8)).save(tmp_path / "flat.jpg", quality=100)
    jpg = read_texture(tmp_path / "flat.jpg", srgb=False)
    assert jpg.shape == (16, 16, 3)
    np.testing.assert_allclose(jpg, np.broadcast_to([200 / 255, 100 / 255, 30 / 255], jpg.shape), atol=1.5 / 255)


@pytest.mark.parametrize("content", [None, b"not an image at all", b"\x89PNG\r\n\x1a\n\x00\x00truncated"])
def test_bad_texture_files_raise_naming_the_file(tmp_path, content):
    path = tmp_path / "skin_map.jpg"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(ValueError, match="skin_map.jpg") as err:
        read_texture(path)
    assert isinstance(err.value, ImageFormatError)


def test_bundled_textures_decoded(textures):
    assert set(textures) == {"albedo", "specular", "normal"}
    shapes = {"albedo": (1024, 1024, 3), "specular": (1024, 1024, 1), "normal": (1024, 1024, 3)}
    for key, tex in textures.items():
        assert tex.shape == shapes[key] and tex.dtype == np.float32, key
        assert_finite(tex)
    np.testing.assert_allclose(np.linalg.norm(textures["normal"].astype(np.float64), axis=-1), 1.0, atol=1e-6)
    with Image.open(_bundled("albedo")) as im:
        raw = np.asarray(im.convert("RGB"), np.float64) / 255.0
    # Decoded with the closed form, and flipped: texture row 0 is the file's last row (row 0 at v = 1).
    np.testing.assert_allclose(textures["albedo"], _srgb_decode_reference(raw[::-1]), rtol=1e-5, atol=1e-7)
    with Image.open(_bundled("specular")) as im:
        spec = np.asarray(im.convert("L"), np.float64) / 255.0
    np.testing.assert_allclose(textures["specular"][..., 0], spec[::-1], atol=1e-7)  # data map: not decoded
    with Image.open(_bundled("normal")) as im:
        nraw = 2.0 * np.asarray(im.convert("RGB"), np.float64)[::-1] / 255.0 - 1.0
    np.testing.assert_allclose(textures["normal"], nraw / np.linalg.norm(nraw, axis=-1, keepdims=True), atol=1e-6)


def test_bundled_files_are_the_scans_own(shared_data):
    folder = shared_data / "meshes" / "lee_perry_smith_textures"
    for key, name in SHARED_NAMES.items():
        digest = hashlib.sha256(_bundled(key).read_bytes()).hexdigest()
        assert digest == hashlib.sha256((folder / name).read_bytes()).hexdigest(), key
    license_text = _bundled("albedo").parent.joinpath("lee_perry_smith_LICENSE.txt").read_text()
    assert "Creative Commons Attribution 3.0" in license_text and "Lee Perry-Smith" in license_text


# --- orientation ------------------------------------------------------------------------------------------------

def _face_patches(surface):
    """Cheeks, eyebrows and forehead located from geometry alone (fractions of the head width W from the nose
    tip, front-facing samples); the lips are skin_regions' label."""
    regions = M.skin_regions(surface)
    rel = (np.asarray(surface.position, np.float64) - regions.nose_tip) / regions.head_width
    front = np.asarray(surface.normal)[:, 2] > 0.4
    ax, y = np.abs(rel[:, 0]), rel[:, 1]
    cheeks = front & (ax > 0.22) & (ax < 0.34) & (y > -0.12) & (y < 0.02)
    brows = front & (ax > 0.10) & (ax < 0.28) & (y > 0.22) & (y < 0.27)
    forehead = front & (ax < 0.20) & (y > 0.35) & (y < 0.45)
    lips = regions.labels == M.LIPS
    for name, mask in (("cheeks", cheeks), ("brows", brows), ("forehead", forehead), ("lips", lips)):
        assert mask.sum() >= 40, f"too few {name} samples ({mask.sum()}) to compare"
    return lips, cheeks, brows, forehead


def _looks_like_a_face(surface, textures):
    rho = np.asarray(M.skin_maps(surface, textures).rho_d, np.float64)
    lips, cheeks, brows, forehead = _face_patches(surface)
    redness = rho[:, 0] / rho[:, 1]
    luminance = rho @ np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 luminance of linear RGB
    return (np.median(redness[lips]) / np.median(redness[cheeks]),
            np.median(luminance[brows]) / np.median(luminance[forehead]))


def test_texture_orientation_on_the_face(surface, textures):
    """Lips redder than the cheeks, eyebrows darker than the forehead: measured 1.16 and 0.33 with the
    bundled orientation; the v-flipped one (glTF's v-down rule applied to trimesh's uv) gives 0.99 and 1.02."""
    lips_vs_cheeks, brows_vs_forehead = _looks_like_a_face(surface, textures)
    assert lips_vs_cheeks > 1.08
    assert brows_vs_forehead < 0.6
    flipped = {key: tex[::-1] for key, tex in textures.items()}
    lips_vs_cheeks, brows_vs_forehead = _looks_like_a_face(surface, flipped)
    assert lips_vs_cheeks < 1.05 and brows_vs_forehead > 0.8  # the test tells the two orientations apart


def test_normal_map_green_points_up_the_stored_image():
    """A tangent-space normal map is the gradient of a height field, so its slope field is curl-free in the
    image axes it was baked in. With green read as 'up the stored image' (OpenGL), the smoothed field's curl is
    0.43x that with green read as 'down' (DirectX): measured 0.0020 vs 0.0047 (sigma 4 px; JPEG noise hides it
    at the pixel scale)."""
    n = read_texture(_bundled("normal"), srgb=False).astype(np.float64) * 2.0 - 1.0
    p, q_up = (gaussian_filter(-n[..., k] / n[..., 2], 4.0) for k in (0, 1))
    # The slopes along x (columns, right) and y_img (rows, down): dh/dy_img = -dh/dY_up.
    inner = (slice(100, 900), slice(100, 900))

    def rms_curl(q_down):
        dp_dy = np.gradient(p, axis=0)[inner]
        dq_dx = np.gradient(q_down, axis=1)[inner]
        return np.sqrt(np.mean((dp_dy - dq_dx) ** 2))

    up, down = rms_curl(-q_up), rms_curl(q_up)
    assert up < 0.6 * down, (up, down)


def test_bitangent_is_the_stored_images_up(head):
    """The bundled maps give +Y along b = n x t; that equals green-up-the-image only if b points up the stored
    image, i.e. along dP/d(1 - v) with trimesh's v (file row 0 at v = 0). Measured: 98.4 % of all samples,
    99.94 % above the neck; the rest lie on the bust's cut-off base (y < -70 mm) and in folds of the eyelids."""
    s = stage.texel_samples(head, 64)
    V, F, UV = head.vertices, head.faces, head.uv
    f = F[np.asarray(s.face)]
    e1, e2 = V[f[:, 1]] - V[f[:, 0]], V[f[:, 2]] - V[f[:, 0]]
    d1, d2 = UV[f[:, 1]] - UV[f[:, 0]], UV[f[:, 2]] - UV[f[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    dp_dv = (e2 * d1[:, :1] - e1 * d2[:, :1]) / det[:, None]
    agrees = np.sum(np.asarray(s.bitangent, np.float64) * -dp_dv, axis=1) > 0
    above_neck = np.asarray(s.position)[:, 1] > -50.0
    assert agrees.mean() > 0.95 and agrees[above_neck].mean() > 0.995


# --- the mapping --------------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def texture_grid_samples(head):
    """20000 samples of the head's 1024^2 texel grid (rasterised once for both filters)."""
    s = stage.texel_samples(head, 1024)
    return s.subset(np.random.default_rng(0).choice(s.num_samples, 20000, replace=False))


@pytest.mark.parametrize("filter", ["box", "bilinear"])
def test_filters_at_texture_resolution_return_the_texture(texture_grid_samples, textures, filter):
    """At a 1024^2 grid over the 1024^2 maps both filters return texel (row, column) = the sample's grid cell
    (measured max error 3.5e-8: the float32 uv)."""
    s = texture_grid_samples
    idx = np.asarray(s.texel_index)
    row, col = idx // 1024, idx % 1024
    t = M.skin_maps(s, textures, filter=filter)
    np.testing.assert_allclose(np.asarray(t.rho_d) / M.ALBEDO_SCALE, textures["albedo"][row, col], atol=1e-6)
    spec = textures["specular"][row, col]
    np.testing.assert_allclose(np.asarray(t.rho_s), M.F0_SKIN * (0.5 + spec), atol=1e-7)


def test_box_filter_is_the_footprint_mean(head, textures):
    """At 256^2 each texel covers 4 x 4 map texels: the box filter returns their mean (to float32), which
    bilinear interpolation at the texel centre does not (it sees the central 2 x 2 only: up to 0.12 off)."""
    s = stage.texel_samples(head, 256)
    idx = np.asarray(s.texel_index)
    block = textures["albedo"].astype(np.float64).reshape(256, 4, 256, 4, 3).mean(axis=(1, 3))[idx // 256, idx % 256]
    box = np.asarray(M.skin_maps(s, textures).rho_d, np.float64) / M.ALBEDO_SCALE
    bilinear = np.asarray(M.skin_maps(s, textures, filter="bilinear").rho_d, np.float64) / M.ALBEDO_SCALE
    np.testing.assert_allclose(box, block, atol=1e-6)
    assert np.abs(bilinear - block).max() > 0.05


def test_truth_fields_shapes_ranges(surface, truth):
    P = surface.num_samples
    shapes = {"rho_d": (P, 3), "rho_s": (P, 1), "alpha": (P, 1), "normal": (P, 3), "tangent": (P, 3),
              "mfp": (P, 3), "regions": (P,)}
    for name, shape in shapes.items():
        assert getattr(truth, name).shape == shape, name
    assert_finite(truth)
    rho_d, rho_s, alpha = (np.asarray(a, np.float64) for a in (truth.rho_d, truth.rho_s, truth.alpha))
    assert rho_d.min() >= 0 and rho_d.max() <= M.ALBEDO_MAX
    assert 0.35 < np.median(rho_d[:, 0]) < 0.55  # skin's total diffuse albedo in red (Jensen 2001: 0.44-0.63)
    assert np.all(np.median(rho_d, axis=0) == np.sort(np.median(rho_d, axis=0))[::-1])  # red > green > blue
    assert M.F0_SKIN == pytest.approx(0.02778, abs=1e-5)
    assert rho_s.min() >= 0.5 * M.F0_SKIN - 1e-7 and rho_s.max() <= 1.5 * M.F0_SKIN + 1e-7
    assert alpha.min() >= 0.25 - 1e-7 and alpha.max() <= 0.45 + 1e-7
    # Glossier where shinier: alpha falls exactly as rho_s rises (one spec value drives both).
    assert np.corrcoef(rho_s[:, 0], alpha[:, 0])[0, 1] < -0.999
    n, t = np.asarray(truth.normal, np.float64), np.asarray(truth.tangent, np.float64)
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-5)
    assert np.abs(np.sum(n * t, axis=1)).max() < 1e-5


def test_normal_map_perturbation_is_bounded_and_unbiased(surface, truth):
    """The detail normals stay within 60 degrees of the mesh normal (measured max 25 at 128^2, 39 at 256^2) and
    average to it: in the surface's own frame the area-weighted mean tilt is (-0.005, -0.004) against a spread
    of 0.03 per axis. A normal map holds detail, not the shape."""
    n_geo = np.asarray(surface.normal, np.float64)
    n = np.asarray(truth.normal, np.float64)
    cos = np.sum(n * n_geo, axis=1)
    assert cos.min() > np.cos(np.radians(60.0))
    assert cos.mean() > 0.99
    t, b = np.asarray(surface.tangent, np.float64), np.asarray(surface.bitangent, np.float64)
    tilt = np.stack([np.sum(n * t, axis=1), np.sum(n * b, axis=1)], axis=1)
    area = np.asarray(surface.area, np.float64)[:, None]
    mean_tilt = np.sum(tilt * area, axis=0) / area.sum()
    assert np.all(np.abs(mean_tilt) < 0.01), mean_tilt
    assert np.all(tilt.std(axis=0) > 0.01)  # and it does perturb: the spread is 3x the bias bound


def test_mfp_larger_on_nose_and_ears(surface, truth):
    mfp = np.asarray(truth.mfp, np.float64)
    labels = np.asarray(truth.regions)
    _, cheeks, _, _ = _face_patches(surface)
    base = np.asarray(M.SKIN_DMFP_MM)
    np.testing.assert_allclose(np.median(mfp[cheeks], axis=0), base, rtol=1e-6)
    for region in (M.NOSE, M.EARS):
        assert (labels == region).sum() >= 30, M.REGION_NAMES[region]
        ratio = np.median(mfp[labels == region], axis=0) / base
        assert np.all(ratio > 1.0 + 0.8 * (M.REGION_MFP_GAIN[region] - 1.0)), (M.REGION_NAMES[region], ratio)
    assert np.all(mfp[:, 0] > mfp[:, 1]) and np.all(mfp[:, 1] > mfp[:, 2])  # red scatters farthest
    # Smooth transitions: ramps, not a step (samples strictly between the base and the region's full gain).
    scale = mfp[:, 0] / base[0]
    ramp = (scale > 1.02) & (scale < M.REGION_MFP_GAIN[M.EARS] - 0.02)
    assert ramp.sum() > 0.2 * (scale > 1.02).sum()


def test_regions_found_from_geometry(surface):
    r = M.skin_regions(surface)
    p = np.asarray(surface.position, np.float64)
    assert r.nose_tip[2] == pytest.approx(p[:, 2].max())
    assert r.ears[0, 0] > 0 > r.ears[1, 0] and abs(r.ears[0, 1] - r.ears[1, 1]) < 0.1 * r.head_width
    assert r.lips[1] < r.nose_tip[1] and r.lips[2] > r.nose_tip[2] - 0.15 * r.head_width
    assert np.all(r.weights.sum(axis=1) >= 1.0 - 1e-12)  # column 0 is 1 - the largest region weight
    assert np.all(r.weights >= 0) and np.all(r.weights <= 1)
    ears = p[r.labels == M.EARS]
    assert np.all(np.abs(ears[:, 0]) > 0.3 * r.head_width)  # lateral
    nose = p[r.labels == M.NOSE]
    assert np.all(np.abs(nose[:, 0] - r.nose_tip[0]) < 0.2 * r.head_width) and np.all(nose[:, 2] > 0)


def test_base_mfp_follows_jensen_skin_ordering():
    """Jensen et al. 2001's measured skin (dipole 1/sigma_tr, sigma_tr = sqrt(3 sigma_a sigma_t')) is longest in
    red and shortest in blue, like SKIN_DMFP_MM; those measured lengths are 2.3-4x longer (forearm in vivo)."""
    for name in ("skin1", "skin2"):
        m = skin_bssrdf.JENSEN2001[name]
        sa, ssp = np.asarray(m.sigma_a), np.asarray(m.sigma_s_prime)
        ld = 1.0 / np.sqrt(3.0 * sa * (sa + ssp))
        assert np.all(np.diff(ld) < 0) and np.all(np.diff(M.SKIN_DMFP_MM) < 0)
        assert np.all(ld > np.asarray(M.SKIN_DMFP_MM))


def test_truth_as_material_maps(surface, truth):
    maps = truth.maps(surface)
    assert np.all(np.asarray(maps.model) == M.SUBSURFACE)
    np.testing.assert_allclose(np.asarray(maps.alpha), np.repeat(np.asarray(truth.alpha), 2, axis=1))
    np.testing.assert_allclose(np.asarray(maps.mfp), np.asarray(truth.mfp))
    profile = maps.profile()
    assert_finite(profile.d)
    assert np.all(np.asarray(profile.d) > 0)


def test_skin_maps_refuses_bad_arguments(surface, textures):
    with pytest.raises(ValueError, match="normal"):
        M.skin_maps(surface, {"albedo": textures["albedo"], "specular": textures["specular"]})
    with pytest.raises(ValueError, match="albedo"):
        M.skin_maps(surface, {**textures, "albedo": textures["albedo"][..., :2]})
    bad = textures["specular"].copy()
    bad[3, 3] = np.nan
    with pytest.raises(ValueError, match="specular"):
        M.skin_maps(surface, {**textures, "specular": bad})
    with pytest.raises(ValueError, match="filter"):
        M.skin_maps(surface, textures, filter="nearest")
    with pytest.raises(ValueError, match="mfp"):
        M.skin_maps(surface, textures, mfp=(1.0, 0.0, 0.3))
    with pytest.raises(ValueError, match="region_gain"):
        M.skin_maps(surface, textures, region_gain=(1.0, 2.0))
    with pytest.raises(ValueError, match="albedo_scale"):
        M.skin_maps(surface, textures, albedo_scale=-1.0)
