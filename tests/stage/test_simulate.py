"""Simulation checks: closed forms, polarisation, gradient illumination,
texel/image agreement, subsurface, bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import skin_bssrdf
import stage

from ..scenes import plane, uv_sphere


def _material(P, rho=1.0, alpha=0.2):
    f = lambda v, c: jnp.full((P, c), v, jnp.float32)  # noqa: E731
    return brdf.lambert_ggx(f(rho, 3), f(0.04, 1), f(alpha, 1))


@pytest.fixture(scope="module")
def scene():
    mesh = uv_sphere(radius=50.0, n_lat=32, n_lon=64)
    surf = stage.texel_samples(mesh, 32)
    rig = stage.geodesic_dome(2)  # 162 distant lights
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=8, width=64, height=64)
    lv = stage.light_visibility(mesh, surf, rig, packed=True)
    cv = stage.camera_visibility(mesh, surf, [cam])
    mat = _material(surf.num_samples)
    caps = {pol: stage.simulate(surf, rig, [cam], mat, lv, cv, polarization=pol) for pol in (None, "parallel", "cross")}
    return dict(mesh=mesh, surf=surf, rig=rig, cam=cam, lv=lv, cv=cv, caps=caps)


def test_white_lambertian_sphere_gives_the_closed_form(scene):
    # Every light weighted by solid angle / irradiance = a uniform sky of radiance 1; a white
    # Lambertian surface then reflects radiance (1/pi) * integral of cos over the hemisphere = 1.
    cross = scene["caps"]["cross"]
    white = stage.Capture(2 * cross.radiance, cross.mask, cross.rig, cross.cameras)  # 2 x cross = the diffuse part
    full = np.asarray(stage.gradient_images(white))[0, 0]
    seen = scene["cv"][0]
    assert seen.sum() > 300
    # 162 lights stand in for the sphere: the Voronoi quadrature of the clamped cosine is good to 0.5%.
    np.testing.assert_allclose(full[seen], 1.0, rtol=5e-3)
    for cap in scene["caps"].values():
        assert np.all(np.isfinite(np.asarray(cap.radiance)))


def test_polarisation_separates_diffuse_and_specular(scene):
    caps = scene["caps"]
    par, cross, plain = (np.asarray(caps[k].radiance, np.float64) for k in ("parallel", "cross", None))
    surf, rig, cam = scene["surf"], scene["rig"], scene["cam"]
    # Cross-polarised: only (half of) the diffuse reflection; parallel adds the whole specular.
    diffuse_only = stage.simulate(surf, rig, [cam], brdf.Lambert(jnp.ones((surf.num_samples, 3), jnp.float32)),
                                  scene["lv"], scene["cv"])
    np.testing.assert_allclose(2 * cross, np.asarray(diffuse_only.radiance), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(2 * cross + (par - cross), plain, rtol=1e-5, atol=1e-6)
    assert (par - cross).max() > 0.05  # the specular lobe is really there
    np.testing.assert_array_equal(np.asarray(caps["cross"].mask), np.asarray(caps[None].mask))


def test_gradient_illumination_normals(scene):
    seen = scene["cv"][0]
    n_true = np.asarray(scene["surf"].normal, np.float64)[seen]
    cross, par = scene["caps"]["cross"], scene["caps"]["parallel"]
    g_diffuse = stage.gradient_images(cross)[0]
    n = np.asarray(stage.diffuse_normals(g_diffuse), np.float64)[seen]
    err = np.degrees(np.arccos(np.clip(np.sum(n * n_true, 1), -1, 1)))
    assert err.max() < 1.0, err.max()  # the bound: within 1 degree on a convex diffuse object
    # Specular normals from parallel - cross (Ma et al. 2007): the GGX lobe (alpha 0.2) is sampled
    # by 162 lights ~17 degrees apart, so its centroid is only good to a few degrees.
    g_spec = stage.gradient_images(stage.Capture(par.radiance - cross.radiance, par.mask, par.rig, par.cameras))[0]
    wo_j = scene["cam"].view_directions(scene["surf"].position)
    wo = np.asarray(wo_j)
    ns = np.asarray(stage.specular_normals(g_spec, wo_j), np.float64)[seen]
    cos_v = np.sum(n_true * wo[seen], 1)
    central = cos_v > np.cos(np.deg2rad(45))  # away from grazing, where the lobe is cut by the horizon
    err_s = np.degrees(np.arccos(np.clip(np.sum(ns * n_true, 1), -1, 1)))[central]
    assert np.median(err_s) < 2.0 and err_s.max() < 6.0, (np.median(err_s), err_s.max())


def test_texel_and_image_space_agree():
    # A plane seen by an orthographic camera whose pixel centres sit exactly on the texel
    # centres: both paths must give the same samples and the same radiance (float32).
    mesh = plane(size=100.0, n=4)
    cam = stage.orthographic((0.0, 500.0, 0.0), up=(0.0, 0.0, -1.0), extent_mm=100.0, width=32, height=32)
    rig = stage.make_rig(np.array([[0.0, 300, 0], [200.0, 150, 0], [-100.0, 100, 250], [0, -300.0, 0]]), 1e5)
    out = []
    for surf in (stage.texel_samples(mesh, 32), stage.image_samples(mesh, cam)):
        order = np.argsort(np.asarray(surf.texel_index))
        lv = stage.light_visibility(mesh, surf, rig)
        cv = stage.camera_visibility(mesh, surf, [cam])
        cap = stage.simulate(surf, rig, [cam], _material(surf.num_samples, 0.5, 0.3), lv, cv)
        out.append((surf.subset(order), np.asarray(cap.radiance)[:, :, order], np.asarray(cap.mask)[:, :, order]))
    (st, rt, mt), (si, ri, mi) = out
    assert st.num_samples == si.num_samples == 32 * 32
    np.testing.assert_allclose(np.asarray(si.position), np.asarray(st.position), atol=1e-3)
    np.testing.assert_allclose(np.asarray(si.area), np.asarray(st.area), rtol=1e-4)
    np.testing.assert_allclose(np.asarray(si.uv), np.asarray(st.uv), atol=1e-5)
    np.testing.assert_array_equal(mi, mt)
    assert rt.max() > 0.1
    np.testing.assert_allclose(ri, rt, rtol=1e-4, atol=1e-6)


def test_subsurface_plane_matches_total_reflectance():
    mesh = plane(size=24.0, n=4)
    surf = stage.texel_samples(mesh, 32)
    profile = skin_bssrdf.Dipole(jnp.array([0.05, 0.1, 0.2]), jnp.array([1.0, 1.0, 1.0]), 1.4)
    op = skin_bssrdf.DiffusionOperator.build(np.asarray(surf.position), np.asarray(surf.area), 4.0)
    rig = stage.make_rig(np.array([[0, 1.0, 0], [1, 0, 0], [0, 0, 1], [-1, -1, -1.0]]), 1.0, near_field=False)
    cam = stage.look_at((0.0, 1000.0, 0.0), up=(0.0, 0.0, -1.0), fov_deg=5, width=32, height=32)
    lv = stage.light_visibility(mesh, surf, rig)
    cv = stage.camera_visibility(mesh, surf, [cam])
    cap = stage.simulate(surf, rig, [cam], None, lv, cv, subsurface=stage.Subsurface(profile, op, 1.4))
    r = np.asarray(cap.radiance, np.float64)
    assert np.all(np.isfinite(r))
    p = np.asarray(surf.position)
    centre = np.hypot(p[:, 0], p[:, 2]) < 2.0
    # Light 0 at normal incidence, camera overhead: L = F_t(1)^2 / pi * M with M the operator's
    # exitance under unit irradiance (Jensen et al. 2001 eq. 5) -- exact up to float32 --
    t1 = 1 - float(np.asarray(brdf.fresnel_dielectric(jnp.ones((1, 1)), 1.4))[0, 0])
    captured = np.asarray(op.captured(profile), np.float64)[centre]
    np.testing.assert_allclose(r[0, 0, centre], t1 * t1 / np.pi * captured, rtol=1e-4)
    # -- and, over an infinite plane, M = R_total - tail(4 mm): 5% for the operator's quadrature
    # on a 0.75 mm texel grid (it under-counts the profile's peak at r = 0).
    expect = t1 * t1 / np.pi * np.asarray(profile.total() - op.tail(profile), np.float64)
    np.testing.assert_allclose(r[0, 0, centre].mean(0), expect, rtol=5e-2)
    # Light 1 grazes along +x (cos_i = 0): nothing enters, nothing leaves. Light 3 is below.
    np.testing.assert_allclose(r[0, 3], 0.0, atol=1e-9)
    # Cross-polarised subsurface is depolarised: half passes.
    cross = stage.simulate(surf, rig, [cam], None, lv, cv, subsurface=stage.Subsurface(profile, op, 1.4),
                           polarization="cross")
    np.testing.assert_allclose(np.asarray(cross.radiance), 0.5 * r, rtol=1e-5, atol=1e-9)


def test_bad_simulation_input(scene):
    surf, rig, mat = scene["surf"], scene["rig"], _material(scene["surf"].num_samples)
    away = stage.look_at((0.0, 0.0, 1000.0), target=(0.0, 0.0, 2000.0))
    with pytest.raises(ValueError, match="camera 0 .* every surface sample behind it"):
        stage.simulate(surf, rig, [away], mat, scene["lv"], scene["cv"])
    with pytest.raises(ValueError, match="light_visibility must have shape"):
        stage.simulate(surf, rig, [scene["cam"]], mat, np.ones((3, 3), bool), scene["cv"])
    with pytest.raises(ValueError, match="polarization"):
        stage.simulate(surf, rig, [scene["cam"]], mat, scene["lv"], scene["cv"], polarization="circular")


def test_streamed_chunks_reassemble_the_capture(scene):
    # Chunked over samples and lights (last chunks padded): the same numbers as one simulate call.
    surf, rig, cam = scene["surf"], scene["rig"], scene["cam"]
    ref = scene["caps"][None]
    rad = np.zeros(ref.radiance.shape, np.float32)
    mask = np.zeros(ref.mask.shape, bool)
    for v, ls, ps, r, m in stage.simulate_chunks(surf, rig, [cam], _material(surf.num_samples), scene["lv"],
                                                 scene["cv"], light_chunk=50, sample_chunk=400):
        assert r.shape[:2] == m.shape
        rad[v, ls, ps] = np.asarray(r)
        mask[v, ls, ps] = m
    np.testing.assert_allclose(rad, np.asarray(ref.radiance), rtol=1e-5, atol=1e-7)
    np.testing.assert_array_equal(mask, np.asarray(ref.mask))


def test_progress_follows_the_one_protocol(scene):
    """simulate reports (phase, done, total): done rises from 0 to total (views x lights)."""
    surf, rig = scene["surf"], scene["rig"]
    calls = []
    stage.simulate(surf, rig, [scene["cam"]], _material(surf.num_samples), scene["lv"], scene["cv"], light_chunk=64,
                   progress=lambda *a: calls.append(a))
    L = rig.num_lights
    assert calls[0] == ("simulate", 0, L) and calls[-1] == ("simulate", L, L)
    assert all(b[1] > a[1] for a, b in zip(calls, calls[1:], strict=False))


def test_float64_maps_give_a_float64_capture_computed_in_float64(scene):
    """One float policy (the widest floating input): float32 maps on the float32 geometry give a float32
    capture; float64 maps give a float64 one equal (to 1e-12) to the capture of the geometry, rig and camera
    cast to float64 by hand, and 1e-4 away from the float32 one (float32's rounding, not a narrowing)."""
    surf, rig, cam, lv, cv = (scene[k] for k in ("surf", "rig", "cam", "lv", "cv"))
    P = surf.num_samples
    mat32 = _material(P, rho=0.6)
    mat64 = jax.tree_util.tree_map(lambda x: x.astype(jnp.float64), mat32)
    cap32 = stage.simulate(surf, rig, [cam], mat32, lv, cv)
    cap64 = stage.simulate(surf, rig, [cam], mat64, lv, cv)
    assert cap32.radiance.dtype == jnp.float32 and cap64.radiance.dtype == jnp.float64
    f64 = lambda t: jax.tree_util.tree_map(  # noqa: E731
        lambda x: x.astype(jnp.float64) if jnp.issubdtype(x.dtype, jnp.floating) else x, t)
    ref = stage.simulate(f64(surf), f64(rig), [f64(cam)], mat64, lv, cv)
    np.testing.assert_allclose(np.asarray(cap64.radiance), np.asarray(ref.radiance), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(np.asarray(cap32.radiance), np.asarray(cap64.radiance), rtol=1e-4, atol=1e-6)
