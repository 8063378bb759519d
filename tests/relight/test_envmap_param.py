"""Angular, mirror-ball and cube-map parameterisations: conventions, solid
angles, round trips through lat-long; importance sampling; image resampling
checked against kornia."""

import jax.numpy as jnp
import numpy as np
import pytest

from relight.envmap import (
    EnvMap,
    angular_directions,
    angular_solid_angles,
    angular_to_latlong,
    cubemap_directions,
    cubemap_solid_angles,
    cubemap_to_latlong,
    direction_to_angular,
    direction_to_cubemap,
    direction_to_mirrorball,
    envmap_integral,
    envmap_pdf,
    envmap_sampler,
    latlong_directions,
    latlong_solid_angles,
    latlong_to_angular,
    latlong_to_cubemap,
    latlong_to_mirrorball,
    mirrorball_directions,
    mirrorball_solid_angles,
    mirrorball_to_latlong,
    sample_envmap,
)
from relight.image import resize_image
from tests.helpers import assert_close
from tests.scenes import envmap


def smooth(d):
    """A smooth positive test function of direction (bands 0-2)."""
    d = np.asarray(d)
    return np.stack([1 + 0.5 * d[..., 0], 1 + 0.3 * d[..., 1] * d[..., 2], 1 + 0.4 * d[..., 2] ** 2], axis=-1)


def test_conventions():
    n = 17  # odd: pixel (8, 8) is the centre; one size keeps the compiled programs few
    da, inside_a = angular_directions(n, jnp.float64)
    dm, inside_m = mirrorball_directions(n, jnp.float64)
    # Angular map: centre -> -z; mirror ball: centre -> +z.
    assert_close(da[8, 8], [0, 0, -1], atol=1e-12)
    assert_close(dm[8, 8], [0, 0, 1], atol=1e-12)
    # Up in the image is +y: pixel (2, 8) has u = 0, v = 1 - 5/17 and the ball
    # reflects (0, 2 v n_z, 2 n_z^2 - 1) there, n_z = sqrt(1 - v^2).
    v = 1 - 5 / 17
    assert_close(dm[2, 8], [0.0, 2 * v * np.sqrt(1 - v * v), 1 - 2 * v * v], atol=1e-12)
    assert_close(da[2, 8], [0.0, np.sin(np.pi * v), -np.cos(np.pi * v)], atol=1e-12)
    faces = np.asarray(cubemap_directions(n, jnp.float64))
    for f, axis in enumerate([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]]):
        assert_close(faces[f, 8, 8], axis, atol=1e-12)
    # Mapping the pixel directions back gives the pixel coordinates.
    rows, cols = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    face, r, c = direction_to_cubemap(jnp.asarray(faces), n)
    assert np.all(np.asarray(face) == np.arange(6)[:, None, None])
    assert_close(r, np.broadcast_to(rows, (6, n, n)), atol=1e-9)
    assert_close(c, np.broadcast_to(cols, (6, n, n)), atol=1e-9)
    for dirs, ok, inverse in ((da, inside_a, direction_to_angular), (dm, inside_m, direction_to_mirrorball)):
        r, c = inverse(dirs, n)
        ok = np.asarray(ok)
        assert_close(np.asarray(r)[ok], rows[ok], atol=1e-9)
        assert_close(np.asarray(c)[ok], cols[ok], atol=1e-9)


def test_solid_angles_sum_to_4pi():
    assert_close(cubemap_solid_angles(32, jnp.float64).sum(), 4 * np.pi, rtol=1e-12)
    # Disk-based maps: pixel-centre inclusion cuts the rim; error ~ rim pixels / total, ~ 1/N.
    assert_close(angular_solid_angles(512, jnp.float64).sum(), 4 * np.pi, rtol=1e-2)
    assert_close(mirrorball_solid_angles(512, jnp.float64).sum(), 4 * np.pi, rtol=1e-2)


def _roundtrip_error(to, back, size, height, exclude_minus_z_deg=0.0):
    env = EnvMap(jnp.asarray(smooth(latlong_directions(height, 2 * height, jnp.float64))))
    out = np.asarray(back(to(env, size), height).radiance)
    d = np.asarray(latlong_directions(height, 2 * height, jnp.float64))
    keep = d[..., 2] > -np.cos(np.radians(exclude_minus_z_deg)) if exclude_minus_z_deg else np.ones(d.shape[:2], bool)
    return np.abs(out - smooth(d))[keep].max()


def test_roundtrips_through_latlong():
    # Two bilinear resamplings of a smooth function (error ~ h^2/8 |f''| ~ 6e-4
    # at pitch h ~ 0.05 rad), plus the cube sampler's clamp in the half-pixel
    # band along face edges: <= |grad f| * h/2 <= 0.8 * 0.021 ~ 0.017 there.
    assert _roundtrip_error(latlong_to_cubemap, cubemap_to_latlong, 48, 64) < 1.7e-2
    # Angular maps stretch azimuth near the rim (+z) by pi r / sin(pi r): excluded
    # is nothing, but the rim's pixels are ~3x coarser: allow 3x.
    assert _roundtrip_error(latlong_to_angular, angular_to_latlong, 192, 64, exclude_minus_z_deg=0.0) < 1e-2
    # The mirror ball's rim holds all of -z's neighbourhood in a thin ring:
    # exclude 30 degrees around -z, where its resolution collapses.
    assert _roundtrip_error(latlong_to_mirrorball, mirrorball_to_latlong, 192, 64, exclude_minus_z_deg=30.0) < 1e-2


def test_cubemap_preserves_energy_of_a_real_map(shared_data):
    env = envmap(shared_data, "uffizi")
    cube = latlong_to_cubemap(env, 96)
    # In float64, as standard promotion summed it (the map is float32; strict promotion wants the cast written).
    energy = np.asarray((cube.astype(jnp.float64) * cubemap_solid_angles(96, jnp.float64)[..., None]).sum((0, 1, 2)))
    # Bilinear point sampling of a map with small bright sources: energy within 2%.
    assert_close(energy, envmap_integral(env), rtol=2e-2)


def test_importance_sampling_tables():
    rng = np.random.default_rng(8)
    img = rng.random((8, 16, 3)) ** 4
    img[2, 5] = 50.0
    s = envmap_sampler(EnvMap(jnp.asarray(img)))
    # The density integrates to 1 over the sphere.
    pdf_pix = np.asarray(envmap_pdf(s, latlong_directions(8, 16, jnp.float64)))
    assert_close((pdf_pix * np.asarray(latlong_solid_angles(8, 16, jnp.float64))).sum(), 1.0, atol=1e-12)
    u = np.random.default_rng(0).random((40000, 2))  # fixed seed
    d, pdf, rad, pix = (np.asarray(a) for a in sample_envmap(s, u))
    assert_close(np.linalg.norm(d, axis=-1), np.ones(40000), atol=1e-12)
    assert_close(pdf, envmap_pdf(s, d), rtol=1e-9)  # each sample lies in the pixel it was drawn from
    # Pixel frequencies follow the table: each within 5 binomial sigmas.
    counts = np.bincount(pix[:, 0] * 16 + pix[:, 1], minlength=128)
    p = np.asarray(s.pixel_prob).reshape(-1)
    assert np.all(np.abs(counts - 40000 * p) <= 5 * np.sqrt(40000 * p * (1 - p)) + 1)
    # Unbiased integration: mean(L / pdf) -> int L dOmega within 5 standard errors.
    est = rad / pdf[:, None]
    se = est.std(0) / np.sqrt(len(est))
    total = (img * np.asarray(latlong_solid_angles(8, 16, jnp.float64))[..., None]).sum((0, 1))
    assert np.all(np.abs(est.mean(0) - total) <= 5 * se)
    # A grey map is sampled in exact proportion: L / pdf is its integral for every sample.
    grey = np.repeat(img[..., :1], 3, axis=-1)
    _, pg, rg, _ = (np.asarray(a) for a in sample_envmap(envmap_sampler(EnvMap(jnp.asarray(grey))), u))
    integral = (grey[..., 0] * np.asarray(latlong_solid_angles(8, 16, jnp.float64))).sum()
    assert_close(rg[:, 0] / pg, np.full(40000, integral), rtol=1e-9)


@pytest.mark.parametrize("size", [(7, 11), (40, 24)])
def test_resize_matches_kornia(size):
    torch = pytest.importorskip("torch")
    kornia = pytest.importorskip("kornia")
    rng = np.random.default_rng(9)
    img = rng.random((20, 16, 3))
    ours = np.asarray(resize_image(jnp.asarray(img), size, antialias=False))
    ref = kornia.geometry.transform.resize(
        torch.from_numpy(img.transpose(2, 0, 1))[None], size, interpolation="bilinear", align_corners=False,
        antialias=False,
    )[0].numpy().transpose(1, 2, 0)
    assert_close(ours, ref, atol=1e-12)
