"""Shared test scenes, built in code: meshes (a plane, a UV sphere, merged meshes), a planar texel grid for the
diffusion operators, the UV sphere written as an OBJ file, the camera-facing part of a sphere seen by one camera
under a dome, the noisy GGX sphere capture that the fit tests share, and what ../shared/data holds (the Light
Stage X directions, cached env maps).

The expensive builders are cached (``functools.lru_cache``: built once per process, so once per pytest-xdist
worker); tests/conftest.py offers them as session-scoped fixtures. Everything they return is immutable (numpy
arrays are returned read-only, JAX arrays and equinox modules are immutable), so sharing one copy is safe.
"""

import functools
import json
from pathlib import Path

import jax.numpy as jnp
import numpy as np

import brdf
import stage
from relight.envmap import load_envmap

ENVMAPS = ["grace", "uffizi", "pisa", "ennis", "venice_sunset_1k", "royal_esplanade_1k"]
SMALL_ENVMAPS = ENVMAPS[:4]

# --------------------------------------------------------------------------- meshes


def plane(size=200.0, n=40, y=0.0):
    """A square in the xz-plane at height y, facing +y, with a UV grid."""
    g = np.linspace(-size / 2, size / 2, n + 1)
    x, z = np.meshgrid(g, g, indexing="xy")
    verts = np.stack([x.ravel(), np.full(x.size, y), z.ravel()], 1)
    uv = np.stack([(x.ravel() + size / 2) / size, 1 - (z.ravel() + size / 2) / size], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    normals = np.tile([0.0, 1.0, 0.0], (len(verts), 1))
    return stage.Mesh(verts, faces, normals, uv, "plane")


def uv_sphere(radius=50.0, n_lat=48, n_lon=96, center=(0.0, 0.0, 0.0), with_uv=True):
    """``stage.uv_sphere``: a latitude-longitude sphere with an equirectangular UV map."""
    return stage.uv_sphere(radius, n_lat, n_lon, center, with_uv)


def small_render_scene(seed: int):
    """(mesh, surface, maps, env, wo) of the render tests: an 8 x 16 sphere on an 8^2 texel grid, uniform
    Lambert + GGX maps, a random 8 x 16 environment (``seed``) and the normals as view directions."""
    from relight import material_maps
    from relight.envmap import EnvMap

    mesh = uv_sphere(50.0, 8, 16)
    surf = stage.texel_samples(mesh, 8)
    maps = material_maps(surf, 0.5, 0.04, 0.3)
    env = EnvMap(jnp.asarray(np.random.default_rng(seed).uniform(0.1, 2.0, (8, 16, 3)), jnp.float32))
    return mesh, surf, maps, env, np.asarray(surf.normal)


def merge(*meshes, uv_of=0):
    """Concatenate meshes; only mesh ``uv_of`` keeps its UVs (others get degenerate UVs)."""
    verts, faces, normals, uvs, off = [], [], [], [], 0
    for i, m in enumerate(meshes):
        verts.append(m.vertices)
        faces.append(m.faces + off)
        normals.append(m.normals)
        uvs.append(m.uv if i == uv_of else np.full((len(m.vertices), 2), -1.0))
        off += len(m.vertices)
    return stage.Mesh(np.concatenate(verts), np.concatenate(faces), np.concatenate(normals), np.concatenate(uvs),
                      "merged")


def texel_grid(n, h, *, m=None):
    """n x m samples on z = 0 with spacing h (mm), row-major: positions [P, 3], areas [P], texel [P, 2]."""
    m = n if m is None else m
    r, c = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    pos = np.stack([c.ravel() * h, r.ravel() * h, np.zeros(n * m)], -1)
    return pos, np.full(n * m, h * h), np.stack([r.ravel(), c.ravel()], -1)


def write_sphere_obj(path, radius=50.0, n_theta=48, n_phi=96) -> Path:
    """Write a UV sphere of ``radius`` (mm) with a lat-long UV atlas (v = 1 at the north pole, +y) as an OBJ file.

    Unlike ``uv_sphere`` its azimuth starts at +z (x = sin(theta) sin(phi)) and the poles are closed by single
    triangles, as a modelling package writes one. Returns ``path``.
    """
    path = Path(path)
    th = np.linspace(0, np.pi, n_theta + 1)
    ph = np.linspace(0, 2 * np.pi, n_phi + 1)
    T, Ph = np.meshgrid(th, ph, indexing="ij")
    d = np.stack([np.sin(T) * np.sin(Ph), np.cos(T), np.sin(T) * np.cos(Ph)], -1).reshape(-1, 3)
    uv = np.stack([Ph / (2 * np.pi), 1 - T / np.pi], -1).reshape(-1, 2)
    W = n_phi + 1
    faces = []
    for i in range(n_theta):
        for j in range(n_phi):
            a, b, c, e = i * W + j, i * W + j + 1, (i + 1) * W + j, (i + 1) * W + j + 1
            if i > 0:
                faces.append((a, c, b))
            if i < n_theta - 1:
                faces.append((b, c, e))
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in radius * d]
    lines += [f"vt {u:.9g} {v:.9g}" for u, v in uv]
    lines += [f"vn {x:.9g} {y:.9g} {z:.9g}" for x, y, z in d]
    lines += [f"f {a + 1}/{a + 1}/{a + 1} {b + 1}/{b + 1}/{b + 1} {c + 1}/{c + 1}/{c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")
    return path


# --------------------------------------------------------------------------- seen spheres and captures


@functools.lru_cache(maxsize=8)
def sphere_view(radius=50.0, res=24, dome=1, distance=1000.0, fov_deg=10.0, size=128, min_cos=0.3):
    """The part of a UV sphere (24 x 48 facets) that one camera on +z sees, under a geodesic dome.

    Args:
        radius: sphere radius (mm).
        res: texel resolution of ``stage.texel_samples``.
        dome: subdivision level of ``stage.geodesic_dome`` (1: 42 lights, 2: 162).
        distance, fov_deg, size: the camera on +z looking at the centre.
        min_cos: samples kept where the normal's z is above this (0: every sample the camera sees).

    Returns:
        (mesh, surface, rig, camera, light visibility [P, L], camera visibility [1, P]) of the kept samples.
    """
    mesh = uv_sphere(radius=radius, n_lat=24, n_lon=48)
    surface = stage.texel_samples(mesh, res)
    rig = stage.geodesic_dome(dome)
    cam = stage.look_at((0.0, 0.0, distance), fov_deg=fov_deg, width=size, height=size)
    lv = stage.light_visibility(mesh, surface, rig)
    cv = stage.camera_visibility(mesh, surface, [cam])
    p = np.asarray(surface.position)
    keep = np.nonzero(cv[0] & (p[:, 2] / radius > min_cos))[0]
    lv, cv = _frozen(np.asarray(lv)[keep]), _frozen(np.asarray(cv)[:, keep])
    return mesh, surface.subset(keep), rig, cam, lv, cv


@functools.lru_cache(maxsize=8)
def noisy_ggx_sphere(res=24, seed=0, noise=0.02):
    """A noisy GGX sphere seen by one camera under a 42-light dome (res 24: ~160 texels, res 16: ~80).

    Random Lambert + GGX parameters per texel (seeded), radiance times (1 + noise N(0, 1)); deterministic, so a
    subprocess that builds it gets the same bytes. Returns (capture, surface).
    """
    _, surface, rig, cam, lv, cv = sphere_view(res=res)
    n = surface.num_samples
    rng = np.random.default_rng(seed)
    rho, f0, alpha = (jnp.asarray(rng.uniform(lo, hi, (n, k)), jnp.float32)
                      for lo, hi, k in ((0.1, 0.8, 3), (0.02, 0.08, 1), (0.15, 0.6, 1)))
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv, cv)
    scale = jnp.asarray(1 + noise * rng.standard_normal(cap.radiance.shape), jnp.float32)
    return stage.Capture(cap.radiance * scale, cap.mask, cap.rig, cap.cameras), surface


# --------------------------------------------------------------------------- directions and ../shared/data


def fibonacci_sphere(n: int) -> np.ndarray:
    """n nearly uniform unit vectors (golden-angle spiral)."""
    i = np.arange(n) + 0.5
    y = 1 - 2 * i / n
    r = np.sqrt(1 - y * y)
    phi = np.pi * (1 + 5**0.5) * i
    return np.stack([r * np.cos(phi), y, r * np.sin(phi)], axis=-1)


def light_stage_x(shared_data: Path) -> np.ndarray:
    """Unit directions [346, 3] from the stage centre to each Light Stage X light."""
    return _lsx(str(shared_data))


@functools.lru_cache(maxsize=2)
def _lsx(folder: str) -> np.ndarray:
    with open(Path(folder) / "lightstage" / "light_stage_x.json") as fh:
        pos = np.asarray(json.load(fh)["positions_cm"], np.float64)
    return pos / np.linalg.norm(pos, axis=1, keepdims=True)


@functools.lru_cache(maxsize=8)
def envmap(shared_data: Path, name: str):
    """The env map ``name`` of ../shared/data/envmaps (loaded once per process)."""
    return load_envmap(Path(shared_data) / "envmaps" / f"{name}.hdr")


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a)
    a.flags.writeable = False
    return a
