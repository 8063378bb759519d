"""Near-field point lights through the whole simulator: a white Lambertian
sphere gives rho/pi I cos_i / d^2 per sample with d and cos_i from geometry,
and a plane sample moved away from a light falls off as the inverse square.

(tests/stage/test_rig.py checks ``Rig.incident`` alone; these go through
``light_visibility`` and ``simulate``.)"""

import jax.numpy as jnp
import numpy as np

import brdf
import stage

from ..scenes import plane, uv_sphere

# Radiance is computed and stored in float32: 1e-5 relative covers its rounding.
RTOL_F32 = 1e-5


def test_white_lambertian_sphere_under_near_field_lights():
    radius, rho = 50.0, 1.0
    mesh = uv_sphere(radius=radius, n_lat=24, n_lon=48)
    surf = stage.texel_samples(mesh, 24)
    # Point lights 120-400 mm from the centre (2.4 to 8 radii: strongly near-field,
    # the light's direction and distance vary over the sphere), with RGB intensities.
    pos = np.array([[0.0, 0.0, 400.0], [300.0, 100.0, 0.0], [-80.0, 90.0, 60.0], [0.0, -200.0, -150.0]])
    inten = np.array([[1e5, 2e5, 3e5], [5e4, 5e4, 5e4], [1e4, 2e4, 4e4], [3e5, 1e5, 2e5]])
    rig = stage.make_rig(pos, inten, near_field=True)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=8, width=32, height=32)
    lv = stage.light_visibility(mesh, surf, rig)
    cv = stage.camera_visibility(mesh, surf, [cam])
    mat = brdf.Lambert(jnp.full((surf.num_samples, 3), rho, jnp.float32))
    cap = stage.simulate(surf, rig, [cam], mat, lv, cv)
    rad = np.asarray(cap.radiance, np.float64)[0]  # [L, P, C]

    # the closed form from the geometry alone, in float64
    p = np.asarray(surf.position, np.float64)
    n = np.asarray(surf.normal, np.float64)
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    to_light = pos[:, None, :] - p[None]  # [L, P, 3]
    d = np.linalg.norm(to_light, axis=-1)
    cos_i = np.einsum("lpk,pk->lp", to_light, n) / d
    expect = rho / np.pi * inten[:, None, :] * (np.maximum(cos_i, 0) / d**2)[..., None]

    lit = np.asarray(lv).T  # [L, P]
    seen = np.asarray(cap.mask)[0]  # lit, seen by the camera and front-facing
    # on a convex sphere the lit set is the front-facing set, apart from a thin band
    # at the terminator where the faceted mesh can shadow a sample whose
    # interpolated normal still faces the light (cos_i < 0.05 there)
    assert np.all(lit[cos_i > 0.05])
    assert not np.any(lit[cos_i <= 0])
    assert not np.any(seen & ~lit)
    assert seen.sum() > 0.15 * seen.size
    np.testing.assert_allclose(rad[seen], expect[seen], rtol=RTOL_F32, atol=0)
    np.testing.assert_array_equal(rad[~lit], 0.0)
    # the light 120 mm away is really near-field: its irradiance varies by more
    # than 2x over the lit half of the sphere
    e2 = (inten[2, 0] / d[2] ** 2)[lit[2]]
    assert e2.max() / e2.min() > 2


def test_inverse_square_for_a_plane_sample_moved_away():
    # One light straight above a small plane at heights 100 and 200 mm: the same
    # sample (at the plane's centre, normal incidence) receives 1/4 the irradiance.
    mesh = plane(size=10.0, n=2)
    surf = stage.texel_samples(mesh, 5)  # an odd grid: the middle texel is at the origin
    p = np.asarray(surf.position, np.float64)
    centre = int(np.argmin(np.linalg.norm(p, axis=1)))
    assert np.linalg.norm(p[centre]) < 1e-4
    cam = stage.look_at((0.0, 500.0, 1.0), fov_deg=5, width=16, height=16)
    mat = brdf.Lambert(jnp.full((surf.num_samples, 3), 0.5, jnp.float32))
    out = {}
    for h in (100.0, 200.0, 400.0):
        # light 0 is the one that moves; the rig needs >= 4 lights (a spherical
        # Voronoi partition), so three more sit below the plane, where they light nothing
        below = [[0.0, -300.0, 0.0], [300.0, -10.0, 0.0], [-300.0, -10.0, 5.0]]
        rig = stage.make_rig(np.array([[0.0, h, 0.0]] + below), 1e4, near_field=True)
        lv = stage.light_visibility(mesh, surf, rig)
        cv = stage.camera_visibility(mesh, surf, [cam])
        cap = stage.simulate(surf, rig, [cam], mat, lv, cv)
        assert np.all(np.asarray(cap.mask)[0, 0]) and not np.any(np.asarray(cap.mask)[0, 1:])
        out[h] = np.asarray(cap.radiance, np.float64)[0, 0]
        d = np.linalg.norm(np.array([0.0, h, 0.0]) - p, axis=1)
        cos_i = (h - p[:, 1]) / d
        # every sample: rho/pi I cos_i / d^2
        np.testing.assert_allclose(out[h][:, 0], 0.5 / np.pi * 1e4 * cos_i / d**2, rtol=RTOL_F32)
    np.testing.assert_allclose(out[100.0][centre] / out[200.0][centre], 4.0, rtol=RTOL_F32)
    np.testing.assert_allclose(out[200.0][centre] / out[400.0][centre], 4.0, rtol=RTOL_F32)
