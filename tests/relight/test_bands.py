"""Work in bands and blocks gives what the whole does: camera-view images rendered in bands of rows
(``stage.Camera.crop``), texel projections, occluders and bilinear taps built in blocks of samples, and
photographs read a light or two at a time into the texel store. Each compares one path with the other on a
small scene, with the block sizes forced small."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import stage
from tests.scenes import small_render_scene, uv_sphere


def _camera(size=(40, 32)):
    mesh = uv_sphere(50.0, 12, 24)
    cam = stage.camera_ring(1, 600.0, target=(0.0, 0.0, 0.0), fov_deg=14.0, width=size[0], height=size[1])[0]
    # Skew and lens distortion: the crop must keep both (the distortion acts on normalised coordinates).
    cam = stage.Camera(K=cam.K.at[0, 1].set(2.0), R=cam.R, t=cam.t, width=cam.width, height=cam.height,
                       dist=jnp.array([0.05, -0.02, 0.001, -0.001, 0.0], jnp.float32))
    return mesh, cam


def test_crop_is_the_window_of_the_image():
    mesh, cam = _camera()
    win = cam.crop(5, 9, 20, 11)
    assert (win.width, win.height) == (20, 11)
    pts = np.asarray(mesh.vertices[::7], np.float32)
    p, z = cam.project(pts)
    q, zq = win.project(pts)
    np.testing.assert_allclose(np.asarray(q) + np.array([5.0, 9.0]), np.asarray(p), atol=2e-4)
    np.testing.assert_array_equal(np.asarray(z), np.asarray(zq))
    hit = stage.primary_hits(mesh, cam, 2)[0]
    np.testing.assert_array_equal(stage.primary_hits(mesh, win, 2)[0], hit[18:40, 10:50])
    for bad in ((0, 0, 41, 1), (-1, 0, 4, 4), (0, 30, 4, 3), (0, 0, 0, 4)):
        with pytest.raises(ValueError, match="Camera.crop"):
            cam.crop(*bad)


def test_render_view_in_bands_is_the_whole_image(monkeypatch):
    """Bands of 4 rows (padded sample counts, one key per band) against one band: the same pixels to 1e-5."""
    import relight.image._preview as preview
    from relight.render import render_view

    mesh, _, maps, env, _ = small_render_scene(3)
    surf = stage.texel_samples(mesh, 8)
    _, cam = _camera((24, 20))
    whole = render_view(maps, surf, mesh, cam, env, method="dense", supersample=2)
    monkeypatch.setattr(preview, "BAND_RAYS", 4 * 24 * 4)
    banded = render_view(maps, surf, mesh, cam, env, method="dense", supersample=2)
    assert banded.shape == whole.shape == (20, 24, 3)
    assert np.all(np.isfinite(banded))
    assert float(np.max(whole)) > 0
    np.testing.assert_allclose(banded, whole, rtol=1e-5, atol=1e-6 * float(np.max(whole)))


def test_coverage_and_texture_view_in_bands(monkeypatch):
    import relight.image._preview as preview
    from relight.envmap import EnvMap
    from relight.image import texture_view
    from relight.render import environment_behind, pixel_coverage, y_rotations

    mesh, cam = _camera()
    tex = {"t": np.random.default_rng(0).uniform(0, 1, (16, 16, 2)).astype(np.float32)}
    env = EnvMap(jnp.asarray(np.random.default_rng(1).uniform(0.1, 2.0, (8, 16, 3)), jnp.float32))
    rot = y_rotations([30.0])[0]
    whole = (pixel_coverage(mesh, cam), texture_view(mesh, cam, tex)["t"], environment_behind(env, mesh, cam, rot))
    monkeypatch.setattr(preview, "BAND_RAYS", 3 * 40 * 4)  # bands of 3 rows, the last one of 2
    banded = (pixel_coverage(mesh, cam), texture_view(mesh, cam, tex)["t"], environment_behind(env, mesh, cam, rot))
    assert 0.05 < float(whole[0].mean()) < 0.95  # the sphere covers part of the image
    for a, b in zip(whole, banded, strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-7)


def test_projection_and_occluder_in_blocks(monkeypatch):
    import stage._project_texels as pt
    import stage._visibility as vis

    mesh, cam = _camera()
    surf = stage.texel_samples(mesh, 24)
    occ = stage.Occluder(mesh, surf)
    whole = stage.project_texels(mesh, surf, cam, occluder=occ)
    rig = stage.fibonacci_sphere(12, radius_mm=800.0, near_field=True)
    lit = stage.light_visibility(mesh, surf, rig, occluder=occ)
    monkeypatch.setattr(pt, "_BLOCK", 37)
    monkeypatch.setattr(vis, "_OCCLUDER_BLOCK", 41)
    occ_b = stage.Occluder(mesh, surf)
    for name in ("origin", "surface_origin", "geometric_normal", "normal"):
        np.testing.assert_array_equal(getattr(occ_b, name), getattr(occ, name))
    banded = stage.project_texels(mesh, surf, cam, occluder=occ_b)
    assert whole.rejected == banded.rejected and 0 < int(whole.seen.sum()) < surf.num_samples
    np.testing.assert_array_equal(banded.taps, whole.taps)
    np.testing.assert_array_equal(banded.seen, whole.seen)
    # The projection is compiled per block shape: the same arithmetic, vectorised differently (last bits).
    np.testing.assert_allclose(banded.weights, whole.weights, rtol=0, atol=1e-12)
    np.testing.assert_allclose(banded.cos_o, whole.cos_o, rtol=0, atol=1e-12)
    assert 0 < int(lit.sum()) < lit.size  # some texels see some lights
    np.testing.assert_array_equal(stage.light_visibility(mesh, surf, rig), lit)
    with pytest.raises(ValueError, match="terminator"):
        stage.light_visibility(mesh, surf, rig, terminator=False, occluder=occ)
    with pytest.raises(ValueError, match="samples"):
        stage.light_visibility(mesh, stage.texel_samples(mesh, 8), rig, occluder=occ)


def test_sample_taps_in_blocks(monkeypatch):
    import relight.io._photo_texels as ptx

    rng = np.random.default_rng(2)
    rad = rng.uniform(0, 1, (3, 50, 2)).astype(np.float32)
    ok = rng.uniform(0, 1, (3, 50)) > 0.1
    taps = rng.integers(0, 50, (23, 4))
    w = rng.dirichlet(np.ones(4), 23)
    whole = ptx.sample_taps(rad, ok, taps, w)
    monkeypatch.setattr(ptx, "_TAP_BLOCK", 5)
    banded = ptx.sample_taps(rad, ok, taps, w)
    np.testing.assert_array_equal(banded[0], whole[0])
    np.testing.assert_array_equal(banded[1], whole[1])
    np.testing.assert_allclose(whole[0][1, 4], np.einsum("kc,k->c", rad[1, taps[4]], w[4]), rtol=1e-6)
