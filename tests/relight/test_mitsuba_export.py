"""Mitsuba 3 scene export: the XML parses and references files that exist, the
camera transform is right, and (when ``mitsuba`` is importable; it is not a
project dependency) the scene renders and matches the fitted model on a sphere."""

import xml.etree.ElementTree as ET

import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import relight
import stage
from relight.export import mitsuba_envmap, write_mitsuba_scene
from relight.io import read_maps, write_exr, write_maps

from ..scenes import write_sphere_obj

RADIUS = 50.0  # mm


@pytest.fixture(scope="module")
def sphere(tmp_path_factory):
    folder = tmp_path_factory.mktemp("sphere")
    mesh = stage.load_mesh(write_sphere_obj(folder / "sphere.obj", RADIUS, 48, 96), require_uv=True)
    return mesh, stage.texel_samples(mesh, 64)


RHO_D = (0.5, 0.3, 0.2)
F0 = 0.04
ALPHA = 0.3


def _scene(tmp_path, mesh, surface, env, camera, rho_d=RHO_D, f0=F0):
    maps = relight.material_maps(surface, np.broadcast_to(rho_d, (surface.num_samples, 3)), f0, ALPHA)
    write_maps(tmp_path / "maps", maps, surface)
    tex, _ = read_maps(tmp_path / "maps")
    env_path = tmp_path / "env.exr"
    write_exr(env_path, env)
    return write_mitsuba_scene(tmp_path / "scene", mesh, tex, camera, env_path, spp=64, max_depth=2)


def test_xml_parses_and_references_existing_files(sphere, tmp_path):
    mesh, surface = sphere
    cam = stage.look_at((30.0, 20.0, 200.0), fov_deg=40.0, width=40, height=30)
    path = _scene(tmp_path, mesh, surface, np.ones((8, 16, 3), np.float32), cam)
    root = ET.parse(path).getroot()
    assert root.tag == "scene" and root.get("version").startswith("3.")
    names = [e.get("value") for e in root.iter("string") if e.get("name") == "filename"]
    assert {"mesh.obj", "envmap.exr", "mitsuba/diffuse_x2.exr", "mitsuba/alpha_u.exr", "mitsuba/eta.exr"} <= set(names)
    for n in names:
        assert (path.parent / n).is_file(), n
    assert [e.get("type") for e in root.iter("emitter")] == ["envmap"]
    assert [e.get("type") for e in root.iter("bsdf")][:3] == ["blendbsdf", "diffuse", "roughconductor"]
    sensor = root.find("sensor")
    fov = float(next(e.get("value") for e in sensor.iter("float") if e.get("name") == "fov"))
    assert fov == pytest.approx(40.0, abs=1e-4)
    film = {e.get("name"): int(e.get("value")) for e in sensor.find("film").iter("integer")}
    assert film == {"width": 40, "height": 30}
    M = np.array(sensor.find("transform").find("matrix").get("value").split(), float).reshape(4, 4)
    # Mitsuba camera frame: origin at the camera centre, +z forward, +y up, +x left.
    np.testing.assert_allclose(M[:3, 3], np.asarray(cam.center), atol=1e-3)
    np.testing.assert_allclose(M[:3, 2], np.asarray(cam.forward), atol=1e-6)
    np.testing.assert_allclose(M[:3, 1], -np.asarray(cam.R)[1], atol=1e-6)
    np.testing.assert_allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-6)
    assert np.linalg.det(M[:3, :3]) == pytest.approx(1.0, abs=1e-6)
    # The eta map encodes F0 exactly at normal incidence: ((eta - 1) / (eta + 1))^2 = F0.
    from relight.io import read_exr

    eta = read_exr(path.parent / "mitsuba" / "eta.exr")[..., 0]
    np.testing.assert_allclose(((eta - 1) / (eta + 1)) ** 2, F0, rtol=1e-5)


def test_refuses_missing_envmap_and_orthographic_camera(sphere, tmp_path):
    mesh, surface = sphere
    maps = relight.material_maps(surface, 0.5)
    write_maps(tmp_path / "maps", maps, surface)
    tex, _ = read_maps(tmp_path / "maps")
    cam = stage.look_at((0.0, 0.0, 200.0))
    with pytest.raises(FileNotFoundError, match="nowhere.hdr"):
        write_mitsuba_scene(tmp_path / "s", mesh, tex, cam, tmp_path / "nowhere.hdr")
    env = tmp_path / "env.exr"
    write_exr(env, np.ones((4, 8, 3), np.float32))
    with pytest.raises(ValueError, match="orthographic"):
        write_mitsuba_scene(tmp_path / "s", mesh, tex, stage.orthographic((0.0, 0.0, 200.0)), env)


def _mitsuba():
    mi = pytest.importorskip("mitsuba", reason="mitsuba is not installed (optional; not a project dependency)")
    mi.set_variant("scalar_rgb")
    return mi


def _directional_albedo_normal_incidence(rho_d, f0, alpha, n=256):
    """sum over the hemisphere of f_r cos (white furnace, wo = n) by midpoint quadrature in (theta, phi)."""
    th = (np.arange(n) + 0.5) * (np.pi / 2) / n
    ph = (np.arange(2 * n) + 0.5) * (2 * np.pi) / (2 * n)
    T, P = np.meshgrid(th, ph, indexing="ij")
    wi = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    wo = np.broadcast_to([0.0, 0.0, 1.0], wi.shape)
    m = brdf.lambert_ggx(np.asarray([rho_d]), np.asarray([[f0]]), np.asarray([[alpha]]))
    f = np.asarray(m(jnp.asarray(wi), jnp.asarray(wo)))  # brdf Modules take JAX arrays (their annotations)
    dw = (np.sin(T) * (np.pi / 2 / n) * (2 * np.pi / (2 * n))).reshape(-1, 1)
    return np.sum(f * wi[:, 2:3] * dw, axis=0)


def test_mitsuba_renders_the_fitted_model_under_a_white_furnace(sphere, tmp_path):
    """A convex sphere under a constant environment of radiance 1: the pixel at the
    sphere's centre is the model's directional albedo at normal incidence,
    rho_d + A_spec. The Mitsuba mapping differs from the fitted model only in
    the Fresnel curve (exact dielectric vs Schlick), worth < 1% of the
    specular albedo here; 2% relative tolerance covers that plus Monte Carlo noise."""
    mi = _mitsuba()
    mesh, surface = sphere
    cam = stage.look_at((0.0, 0.0, 400.0), fov_deg=20.0, width=24, height=24)
    path = _scene(tmp_path, mesh, surface, np.ones((16, 32, 3), np.float32), cam)
    img = np.asarray(mi.render(mi.load_file(str(path), spp=256)))
    centre = img[10:14, 10:14].reshape(-1, 3).mean(0)
    expected = _directional_albedo_normal_incidence(RHO_D, F0, ALPHA)
    np.testing.assert_allclose(centre, expected, rtol=0.02)
    # Without the factor 2 in the blend, everything would be half as bright.
    assert expected[2] > 0.2


def test_mitsuba_camera_and_envmap_match_the_stage_frame(sphere, tmp_path):
    """Background pixels show the environment along the camera's rays: with a map
    whose colour encodes the direction (0.5 + 0.5 d), Mitsuba's pixels must equal
    0.5 + 0.5 x (the ray direction of stage.Camera.rays) to the map's resolution."""
    mi = _mitsuba()
    from relight.envmap import latlong_directions

    mesh, surface = sphere
    env = 0.5 + 0.5 * np.asarray(latlong_directions(128, 256), np.float32)
    cam = stage.look_at((60.0, 40.0, 160.0), target=(0.0, 0.0, 0.0), fov_deg=90.0, width=24, height=18)
    path = _scene(tmp_path, mesh, surface, env, cam)
    img = np.asarray(mi.render(mi.load_file(str(path), spp=16)))
    assert img.shape == (18, 24, 3)
    hit = stage.primary_hits(mesh, cam, 3)[0].reshape(18, 3, 24, 3).any(axis=(1, 3))
    ys, xs = np.mgrid[0:18, 0:24] + 0.5
    _, d = cam.rays(np.stack([xs, ys], -1).reshape(-1, 2))
    want = (0.5 + 0.5 * np.asarray(d)).reshape(18, 24, 3)
    bg = ~hit
    assert bg.sum() > 100
    err = np.abs(img[bg] - want[bg])
    assert np.median(err) < 0.01 and err.max() < 0.05, (np.median(err), err.max())
    # The sphere itself is lit, not background-coloured nonsense: finite and positive.
    assert np.all(np.isfinite(img)) and img[hit].min() > 0


def test_an_off_centre_principal_point_renders_where_the_camera_says(sphere, tmp_path):
    """A non-square camera with its principal point 6% right and 9% up of the film's centre: Mitsuba's sensor
    ray through each film position projects back, through the Camera, onto that position (to 1e-2 px over a
    64 x 48 film; a sign error in the offset would put it 7.7 px and 8.6 px off)."""
    mi = _mitsuba()
    mesh, surface = sphere
    base = stage.look_at((60.0, 40.0, 160.0), target=(0.0, 0.0, 0.0), fov_deg=60.0, width=64, height=48)
    K = np.asarray(base.K, np.float64).copy()
    K[0, 2] += 0.06 * 64
    K[1, 2] -= 0.09 * 48
    cam = stage.Camera(K=jnp.asarray(K, jnp.float32), R=base.R, t=base.t, width=64, height=48)
    sensor = mi.load_file(str(_scene(tmp_path, mesh, surface, np.ones((8, 16, 3), np.float32), cam))).sensors()[0]
    film = np.random.default_rng(0).random((40, 2))
    points = []
    for fx, fy in film:
        ray, _ = sensor.sample_ray(0.0, 0.5, mi.ScalarPoint2f(float(fx), float(fy)), mi.ScalarPoint2f(0.5, 0.5))
        o, d = np.array(ray.o, np.float64), np.array(ray.d, np.float64)
        points.append(o + 200.0 * d / np.linalg.norm(d))
    pix, _ = cam.project(jnp.asarray(np.asarray(points)))
    np.testing.assert_allclose(np.asarray(pix, np.float64), film * [64, 48], atol=1e-2)


def test_mitsuba_normal_map_tilts_toward_the_tangent(sphere, tmp_path):
    """Fitted normals tilted by 30 degrees toward the texel tangent (dP/du) go to
    Mitsuba as a tangent-space normalmap. Under an environment lit only on the
    half-space the tilt leans into, a Lambertian texel's radiance is
    rho_d / pi * integral of max(n_w . w, 0) over the lit, geometrically visible
    directions; wrong conventions (tilt toward -t, or toward the bitangent)
    change it by more than 25%. 3% tolerance: Monte Carlo noise and the map's
    bilinear interpolation of normals."""
    mi = _mitsuba()
    mesh, surface = sphere
    n = np.asarray(surface.normal, np.float64)
    t = np.asarray(surface.tangent, np.float64)
    th = np.deg2rad(30.0)
    nw, tw = np.cos(th) * n + np.sin(th) * t, np.cos(th) * t - np.sin(th) * n
    rho = 0.6
    maps = relight.material_maps(surface, rho, 0.0, ALPHA, normal=nw, tangent=tw)
    write_maps(tmp_path / "maps", maps, surface)
    tex, _ = read_maps(tmp_path / "maps")
    # The camera looks at the sphere's u = 0.5 meridian (away from the UV seam at u = 0).
    k = int(np.argmin(np.sum((np.asarray(surface.uv) - 0.5) ** 2, axis=1)))
    n0, t0 = n[k], t[k]
    cam = stage.look_at(tuple(400.0 * n0), fov_deg=6.0, width=16, height=16)
    from relight.envmap import latlong_directions

    d = np.asarray(latlong_directions(256, 512), np.float64)
    env = np.repeat((d @ t0 > 0)[..., None], 3, axis=-1).astype(np.float32)
    env_path = tmp_path / "half.exr"
    write_exr(env_path, env)
    path = write_mitsuba_scene(tmp_path / "scene", mesh, tex, cam, env_path, max_depth=2)
    assert "normalmap" in path.read_text()
    img = np.asarray(mi.render(mi.load_file(str(path), spp=512)))
    got = img[7:9, 7:9].reshape(-1, 3).mean(0)
    # Expected, by quadrature over the sphere of directions.
    m = 400
    u = (np.arange(m) + 0.5) / m
    ct, ph = 1 - 2 * u[:, None], 2 * np.pi * u[None, :]
    st = np.sqrt(1 - ct**2)
    w = np.stack(np.broadcast_arrays(st * np.cos(ph), st * np.sin(ph), ct), -1).reshape(-1, 3)
    nk = np.cos(th) * n0 + np.sin(th) * t0
    lit = (w @ t0 > 0) & (w @ n0 > 0)
    expected = rho / np.pi * np.sum(np.maximum(w @ nk, 0) * lit) * (4 * np.pi / len(w))
    np.testing.assert_allclose(got, expected, rtol=0.03)
    flat = rho / np.pi * np.sum(np.maximum(w @ n0, 0) * lit) * (4 * np.pi / len(w))
    assert expected > 1.25 * flat


def test_mitsuba_envmap_reproduces_relight_pixels(sphere, tmp_path):
    """Mitsuba's envmap rows are nodes from pole to pole (theta = i pi / (H - 1)),
    bilinear; relight's pixels are constant over [i, i + 1] pi / H. Through the
    exported scene (match_envmap, the default), Mitsuba's emitter returns each
    relight pixel's value at its centre and at 3/4 of the way to its corner
    (1e-5 relative: the resampled map blends only within 1/128 pixel of an
    edge here), and the map's integral to 0.2%; the file copied as is
    (match_envmap=False) is off by > 20% at some pixel centre of this random map."""
    mi = _mitsuba()
    from relight.envmap import latlong_directions
    from relight.io import read_exr

    mesh, surface = sphere
    rng = np.random.default_rng(5)
    env = rng.uniform(0.1, 2.0, (8, 16, 3)).astype(np.float32)
    cam = stage.look_at((0.0, 0.0, 400.0), fov_deg=20.0, width=8, height=8)
    h, w = env.shape[:2]

    def lookups(path, dirs):
        emitter = mi.load_file(str(path)).emitters()[0]
        out = []
        for d in dirs:
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*(-d))
            v = emitter.eval(si)
            out.append((v[0], v[1], v[2]))
        return np.asarray(out)

    centre = np.asarray(latlong_directions(h, w), np.float64).reshape(-1, 3)
    # Off-centre: 3/4 of the way to the pixel's upper-left corner, still inside the pixel.
    th = np.pi * (np.arange(h) + 0.5 - 0.375) / h
    ph = 2 * np.pi * (np.arange(w) + 0.5 - 0.375) / w - np.pi
    T, Ph = np.meshgrid(th, ph, indexing="ij")
    off = np.stack([np.sin(T) * np.sin(Ph), np.cos(T), -np.sin(T) * np.cos(Ph)], -1).reshape(-1, 3)
    path = _scene(tmp_path / "a", mesh, surface, env, cam)
    want = env.reshape(-1, 3)
    np.testing.assert_allclose(lookups(path, centre), want, rtol=1e-5)
    np.testing.assert_allclose(lookups(path, off), want, rtol=1e-5)
    # The resampled map's integral (bilinear between nodes: trapezoid rows) equals relight's.
    fine = mitsuba_envmap(env)
    np.testing.assert_allclose(read_exr(path.parent / "envmap.exr"), fine, rtol=1e-6)
    dom = np.asarray(relight.envmap.latlong_solid_angles(h, w))[..., None]
    n = fine.shape[0] - 1
    theta = np.pi * np.arange(n + 1) / n
    rows = fine.mean(axis=1)  # [n + 1, C]: a bilinear row's mean over u is its nodes' mean
    integ = 2 * np.pi * np.trapezoid(rows * np.sin(theta)[:, None], theta, axis=0)
    np.testing.assert_allclose(integ, (env * dom).sum((0, 1)), rtol=2e-3)
    write_maps(tmp_path / "b" / "maps", relight.material_maps(surface, 0.5), surface)
    tex, _ = read_maps(tmp_path / "b" / "maps")
    write_exr(tmp_path / "b" / "env.exr", env)
    raw = write_mitsuba_scene(tmp_path / "b" / "scene", mesh, tex, cam, tmp_path / "b" / "env.exr", match_envmap=False)
    assert np.max(np.abs(lookups(raw, centre) / want - 1)) > 0.2
    with pytest.raises(ValueError, match="lat-long"):
        mitsuba_envmap(np.ones((4, 4, 3)))


def test_mitsuba_schlick_export_matches_the_model_under_a_white_furnace(sphere, tmp_path):
    """fresnel="schlick" (principled metallic = Schlick GGX, blended 0.99 : 0.01
    with diffuse 100 rho_d): the sphere's centre under a constant map is the
    model's directional albedo at normal incidence rho_d + A_spec with our
    Schlick Fresnel; 0.7% relative: Monte Carlo noise of 16 pixels x 256 spp
    and the curvature of the sphere across them (the dielectric export needs 2%)."""
    mi = _mitsuba()
    mesh, surface = sphere
    cam = stage.look_at((0.0, 0.0, 400.0), fov_deg=20.0, width=24, height=24)
    maps = relight.material_maps(surface, np.broadcast_to(RHO_D, (surface.num_samples, 3)), F0, ALPHA)
    write_maps(tmp_path / "maps", maps, surface)
    tex, _ = read_maps(tmp_path / "maps")
    write_exr(tmp_path / "env.exr", np.ones((16, 32, 3), np.float32))
    path = write_mitsuba_scene(tmp_path / "scene", mesh, tex, cam, tmp_path / "env.exr", max_depth=2,
                               fresnel="schlick")
    assert "principled" in path.read_text()
    img = np.asarray(mi.render(mi.load_file(str(path), spp=256)))
    centre = img[10:14, 10:14].reshape(-1, 3).mean(0)
    np.testing.assert_allclose(centre, _directional_albedo_normal_incidence(RHO_D, F0, ALPHA), rtol=7e-3)
    with pytest.raises(ValueError, match="fresnel"):
        write_mitsuba_scene(tmp_path / "s2", mesh, tex, cam, tmp_path / "env.exr", fresnel="conductor")


def test_ply_mesh_is_written_as_obj_with_the_same_uvs(sphere, tmp_path):
    """Mitsuba flips texture v for OBJ, not for PLY: a .ply mesh is converted to
    mesh.obj (its vertices and uvs as stage.load_mesh reads them), so the
    texture set's orientation holds for both inputs."""
    import trimesh

    mesh, surface = sphere
    tm = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False,
                         visual=trimesh.visual.TextureVisuals(uv=np.asarray(mesh.uv)))
    ply = tmp_path / "sphere.ply"
    tm.export(ply)
    maps = relight.material_maps(surface, 0.5)
    write_maps(tmp_path / "maps", maps, surface)
    tex, _ = read_maps(tmp_path / "maps")
    env = tmp_path / "env.exr"
    write_exr(env, np.ones((4, 8, 3), np.float32))
    path = write_mitsuba_scene(tmp_path / "scene", ply, tex, stage.look_at((0.0, 0.0, 200.0)), env)
    root = ET.parse(path).getroot()
    assert [e.get("type") for e in root.iter("shape")] == ["obj"]
    back = stage.load_mesh(path.parent / "mesh.obj")
    ref = stage.load_mesh(ply)
    np.testing.assert_allclose(np.asarray(back.vertices), np.asarray(ref.vertices), rtol=1e-7, atol=1e-6)
    np.testing.assert_allclose(np.asarray(back.uv), np.asarray(ref.uv), atol=1e-7)
    np.testing.assert_allclose(np.asarray(ref.uv), np.asarray(mesh.uv), atol=1e-6)
