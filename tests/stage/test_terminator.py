"""Shadow rays from coarse, smooth-shaded meshes (stage.Occluder): no faceted
shadow terminator (Hanika 2021), no self-intersection at any scale
(Waechter & Binder 2019), and no light through a real occluder."""

import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

import brdf
import stage
from stage._visibility import terminator_point

from ..scenes import merge, uv_sphere

# Directional lights, unit, spread over the sphere (none along an axis, so no
# light grazes a whole ring of the lat-long sphere's facets at once).
_LIGHTS = np.array([[1.0, 0.3, 0.2], [-0.4, 0.8, 0.45], [0.2, -0.5, 0.85], [-0.7, -0.2, -0.6]])
_LIGHTS /= np.linalg.norm(_LIGHTS, axis=1, keepdims=True)


def _distant(dirs):
    """Unit distant lights along ``dirs`` (built directly: make_rig's Voronoi solid angles need 4 lights)."""
    d = np.asarray(dirs, np.float64)
    return stage.Rig(position=jnp.asarray(d * 1e3, jnp.float32), intensity=jnp.ones((len(d), 1), jnp.float32),
                     solid_angle=jnp.full((len(d),), 4 * np.pi / len(d), jnp.float32), near_field=False)


def _irradiance(surface, vis, dirs):
    """Cosine-weighted irradiance [P, L] of unit distant lights with the
    interpolated (shading) normal, as stage's forward model shades them."""
    return np.maximum(np.asarray(surface.normal, np.float64) @ dirs.T, 0.0) * vis


def test_coarse_sphere_terminator_follows_the_smooth_cosine():
    """A sphere of 8 x 16 facets (edges ~20 mm on r = 50 mm) with exact sphere
    normals: its interpolated normal is the smooth sphere's normal
    p / |p|, so the rendered irradiance max(n . l, 0) V must equal the analytic
    smooth-sphere cosine max(p/|p| . l, 0) wherever nothing but the sphere
    itself is in the way (a convex body: everywhere). The flat facets tilt
    away from a grazing light by up to ~11 degrees: shadow rays from the facets
    themselves (before the fix) shadowed texels with cos up to 0.16 (whole
    straight-edged facet strips along the terminator)."""
    mesh = uv_sphere(radius=50.0, n_lat=8, n_lon=16)
    s = stage.texel_samples(mesh, 128)
    vis = np.asarray(stage.light_visibility(mesh, s, _distant(_LIGHTS)))
    p = np.asarray(s.position, np.float64)
    smooth = np.maximum((p / np.linalg.norm(p, axis=1, keepdims=True)) @ _LIGHTS.T, 0.0)
    got = _irradiance(s, vis, _LIGHTS)
    near = (smooth > 0.0) & (smooth < 0.3)  # the terminator band, where facets turn away from the light
    assert near.sum() > 1000
    # float32 sample normals against float64 positions: 1e-6.
    assert np.max(np.abs(got - smooth)[near]) < 1e-6
    assert np.max(np.abs(got - smooth)) < 1e-6
    # Below the smooth horizon nothing is lit (the shading horizon still holds).
    assert not (vis & (smooth <= 0.0)).any()


def test_icosphere_image_samples_have_no_faceted_terminator():
    """The same on an 80-face icosphere (no UVs) sampled in image space
    (stage.image_samples, positions = primary ray hits): every pixel whose
    smooth-sphere cosine toward the light is positive sees it."""
    ico = trimesh.creation.icosphere(subdivisions=1, radius=40.0)
    v = np.asarray(ico.vertices, np.float64)
    mesh = stage.Mesh(v, np.asarray(ico.faces, np.int64), v / np.linalg.norm(v, axis=1, keepdims=True), None, "ico")
    light = np.array([[1.0, 0.1, -0.15]]) / np.linalg.norm([1.0, 0.1, -0.15])
    # A camera looking at the terminator from the side: half the disc lit, half dark.
    cam = stage.look_at((0.0, 0.0, 400.0), fov_deg=14, width=96, height=96)
    s = stage.image_samples(mesh, cam)
    vis = np.asarray(stage.light_visibility(mesh, s, _distant(light)))
    n = np.asarray(s.normal, np.float64)
    cos = n @ light.T
    band = (cos > 0) & (cos < 0.3)
    assert band.sum() > 100
    assert vis[cos > 1e-6].all()
    assert not vis[cos <= 0].any()


def test_a_thin_shell_around_a_coarse_sphere_lets_no_light_through():
    """No leaks: a fine sphere (r = 48.5 mm) cuts through a coarse one (r = 50,
    8 x 16 facets, whose flat facets dip to ~46 mm between the vertices). The
    texels of the coarse sphere inside the shell are enclosed: every ray from
    them hits the shell, although the terminator point of many lies outside it
    (the smooth surface the normals describe is at ~50 mm). The lift must fall
    back to the texel's own point there, and nothing must be lit."""
    coarse = uv_sphere(radius=50.0, n_lat=8, n_lon=16)
    shell = uv_sphere(radius=48.5, n_lat=48, n_lon=96, with_uv=False)
    mesh = merge(coarse, shell)
    s = stage.texel_samples(mesh, 128)
    p = np.asarray(s.position, np.float64)
    r = np.linalg.norm(p, axis=1)
    # The shell's facets lie within 48.5 (1 - cos(pi / 48)) ~ 0.1 mm inside 48.5.
    inside = r < 48.3
    occ = stage.Occluder(mesh, s)
    lifted_out = inside & (np.linalg.norm(terminator_point(mesh, s.face, s.barycentric, p), axis=1) > 48.6)
    assert lifted_out.sum() > 200  # the case the guard exists for does occur
    dirs = np.asarray(brdf.fibonacci_sphere(64), np.float64)
    vis = occ.visible(np.flatnonzero(inside), np.broadcast_to(dirs[None], (int(inside.sum()), len(dirs), 3)))
    assert not vis.any()
    # Near-field lights: the same, segments to points 1 m away.
    rig = stage.make_rig(dirs * 1000.0, near_field=True)
    assert not np.asarray(stage.light_visibility(mesh, s, rig))[inside].any()
    # Outside the shell (around the coarse sphere's vertices) texels do see the lights above them.
    outside = r > 48.8
    assert np.asarray(stage.light_visibility(mesh, s, _distant(dirs)))[outside].any(axis=1).mean() > 0.9


@pytest.mark.parametrize("shift", [0.0, 1e3, 1e6])
def test_no_self_shadowing_far_from_the_origin(shift):
    """The ray-origin offset scales with the coordinates (Waechter & Binder):
    a coarse plane far from the origin sees every distant light above its
    plane, down to 0.5 degree elevation (the float32 ray caster's error grows
    with the coordinates: the earlier fixed offset, 1e-4 of the mesh diagonal,
    self-shadowed the plane at 1e6 mm)."""
    g = np.linspace(-100.0, 100.0, 5)
    x, z = np.meshgrid(g, g, indexing="xy")
    verts = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], 1) + shift
    uv = np.stack([(x.ravel() + 100) / 200, 1 - (z.ravel() + 100) / 200], 1)
    idx = np.arange(25).reshape(5, 5)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    mesh = stage.Mesh(verts, faces, np.tile([0.0, 1.0, 0.0], (25, 1)), uv, "far plane")
    s = stage.texel_samples(mesh, 64)
    elev = np.radians([0.5, 2.0, 10.0, 45.0, 89.0])
    az = np.radians([10.0, 100.0, 200.0, 300.0, 45.0])
    dirs = np.stack([np.cos(elev) * np.cos(az), np.sin(elev), np.cos(elev) * np.sin(az)], 1)
    assert np.asarray(stage.light_visibility(mesh, s, _distant(dirs))).all()
    occ = stage.Occluder(mesh, s)
    # Off the plane by the robust epsilon only (flat: no terminator lift), on the normal's side.
    h = (occ.origin - np.asarray(s.position, np.float64))[:, 1]
    assert (h > 0).all() and (h <= 256 * np.finfo(np.float32).eps * (abs(shift) + 150.0) + 2.0**-16).all()


def test_cameras_see_the_flat_triangles():
    """camera_visibility casts from the triangles themselves (a camera's primary
    rays hit the flat facets): a texel on a facet that faces away from the
    camera is never seen, even where its smooth normal faces it; every texel
    whose facet and normal both face the (unoccluded, convex) camera is."""
    mesh = uv_sphere(radius=50.0, n_lat=8, n_lon=16)
    s = stage.texel_samples(mesh, 128)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=10, width=128, height=128)
    seen = stage.camera_visibility(mesh, s, cam)[0]
    occ = stage.Occluder(mesh, s)
    to_cam = np.asarray(cam.center, np.float64)[None] - occ.surface_origin
    facet = np.sum(to_cam * occ.geometric_normal, axis=1) > 0
    shading = np.sum(to_cam * occ.normal, axis=1) > 0
    assert (shading & ~facet).sum() > 50  # such texels exist on this sphere
    assert not seen[~facet].any()
    assert seen[facet & shading].all()


def test_terminator_off_casts_from_the_facets():
    """``terminator=False``: shadow rays from the flat facets (the origin on the
    triangle), which reproduces the faceted terminator the default removes."""
    mesh = uv_sphere(radius=50.0, n_lat=8, n_lon=16)
    s = stage.texel_samples(mesh, 128)
    flat = stage.Occluder(mesh, s, terminator=False)
    np.testing.assert_array_equal(flat.origin, flat.surface_origin)
    np.testing.assert_array_equal(flat.surface_origin, stage.Occluder(mesh, s).surface_origin)
    vis = np.asarray(stage.light_visibility(mesh, s, _distant(_LIGHTS), terminator=False))
    p = np.asarray(s.position, np.float64)
    smooth = np.maximum((p / np.linalg.norm(p, axis=1, keepdims=True)) @ _LIGHTS.T, 0.0)
    assert np.max(np.abs(_irradiance(s, vis, _LIGHTS) - smooth)) > 0.1
