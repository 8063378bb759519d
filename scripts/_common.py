"""What several scripts share: the machine description, a JSON child-process runner, the argparse and chart
boilerplate, the synthetic scenes of the fit benchmarks (sampled sphere surfaces, a UV-sphere mesh, a
simulated OLAT capture, the per-sample errors of a fit) and the inputs of the speed benchmarks (the head
under the Light Stage X, random direction pairs, the GGX conductor, a random OLAT stack).

Scripts run as ``python scripts/x.py`` from the repository root and import this module as ``_common``: Python
puts the script's own folder first on ``sys.path``. Nothing here is library logic; it only composes the public
API of brdf, stage and relight. Importing it loads no JAX and no numpy (each function imports what it uses): the
memory benchmarks' parent processes import it and must stay small, as Linux keeps ru_maxrss across fork and exec.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # imported where used: a memory benchmark's parent process must not hold JAX (see run_json)
    import relight
    import stage

ROOT = Path(__file__).resolve().parent.parent
FIG = ROOT / "docs" / "figures"
DILIGENT = ROOT.parent / "shared" / "data" / "diligent"


def diligent_objects(names: str):
    """(name, relight.io.DiligentData) for each comma-separated DiLiGenT object found under DILIGENT; a
    missing one is said and skipped."""
    from relight.io import read_diligent

    for name in names.split(","):
        if not (DILIGENT / name).is_dir():
            print(f"{name}: not found under {DILIGENT}, skipped")
            continue
        yield name, read_diligent(DILIGENT / name)

# The per-frame sensor of pattern training and of its chart (1/60 s frames): docs/patterns.md.
PATTERN_SENSOR = dict(exposure=2000.0, read_noise=5.0, shot_noise=True)
PATTERN_CAMERA_EYE = (0.0, 0.0, 1000.0)


# --------------------------------------------------------------------------- machine, processes, arguments, charts


def cpu_model() -> str:
    """The CPU's model name (/proc/cpuinfo), else what ``platform`` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def machine() -> str:
    """One line for a results table: CPU model, core count, JAX version and backend."""
    import jax

    return f"{cpu_model()}, {os.cpu_count()} cores, jax {jax.__version__} ({jax.default_backend()})"


def maxrss_mib() -> float:
    """This process's peak resident set size (MiB; Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_json(cmd: list[str], env: dict | None = None) -> dict:
    """Run a child process from the repository root; its last stdout line is its JSON result.

    A failing child stops the script with the child's command and the tail of its stderr.
    """
    run = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=False, env=env)
    if run.returncode:
        raise SystemExit(f"child failed ({' '.join(map(str, cmd))}):\n{run.stderr[-3000:]}")
    return json.loads(run.stdout.strip().splitlines()[-1])


def run_self_json(script: str, args: list[str], env: dict | None = None) -> dict:
    """``run_json`` of ``python <script> <args>`` with this interpreter (a script that re-runs itself)."""
    return run_json([sys.executable, script, *args], env=env)


def parser(doc: str | None, **kw) -> argparse.ArgumentParser:
    """An ArgumentParser whose description is the first paragraph of the script's docstring."""
    return argparse.ArgumentParser(description=(doc or "").split("\n\n")[0], **kw)


def save_figure(fig, path: Path, dpi: int = 110) -> Path:
    """Write ``fig`` to ``path`` atomically (a temporary file, then a rename: never a half-written figure)."""
    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    fig.savefig(tmp, dpi=dpi)
    os.replace(tmp, path)
    return path


# --------------------------------------------------------------------------- scenes of the fit scripts


def frames_from_normals(n):
    """Tangent / bitangent [P, 3] orthogonal to unit normals n [P, 3] (world +x projected, else +y)."""
    import numpy as np

    n = np.asarray(n, np.float64)
    g = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t = g - n * np.sum(n * g, 1, keepdims=True)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return t, np.cross(n, t)


def make_surface(position, normal) -> stage.Surface:
    """A ``stage.Surface`` of independent samples (positions mm, unit normals)."""
    import jax.numpy as jnp
    import numpy as np

    import stage

    P = len(position)
    t, b = frames_from_normals(normal)
    f = lambda x: jnp.asarray(np.asarray(x), jnp.float32)  # noqa: E731
    return stage.Surface(position=f(position), normal=f(normal), tangent=f(t), bitangent=f(b),
                         uv=f(np.zeros((P, 2))), area=f(np.ones(P)), texel_index=jnp.arange(P),
                         face=jnp.zeros(P, jnp.int32), resolution=(1, P))


def sphere_surface(n: int, seed: int = 0, radius: float = 50.0, min_cos: float = 0.3):
    """n samples on the camera-facing (+z) part of a sphere at the origin, cos(normal, z) >= min_cos."""
    import numpy as np

    rng = np.random.default_rng(seed)
    z = rng.uniform(min_cos, 1.0, n)
    ph = rng.uniform(0, 2 * np.pi, n)
    r = np.sqrt(1 - z * z)
    nrm = np.stack([r * np.cos(ph), r * np.sin(ph), z], 1)
    return make_surface(radius * nrm, nrm)


def tilt(surface: stage.Surface, deg, seed: int = 1) -> stage.Surface:
    """The surface with each shading normal tilted by ``deg`` (scalar or [P]) in a random azimuth."""
    import numpy as np

    rng = np.random.default_rng(seed)
    P = surface.num_samples
    phi = rng.uniform(0, 2 * np.pi, P)
    th = np.deg2rad(np.broadcast_to(np.asarray(deg, np.float64), (P,)))
    T, B, N = (np.asarray(x, np.float64) for x in (surface.tangent, surface.bitangent, surface.normal))
    n = (np.sin(th) * np.cos(phi))[:, None] * T + (np.sin(th) * np.sin(phi))[:, None] * B + np.cos(th)[:, None] * N
    return make_surface(np.asarray(surface.position), n / np.linalg.norm(n, axis=1, keepdims=True))


def front_camera(distance: float = 1000.0):
    """A 256 x 256 camera on +z at ``distance`` (mm) looking at the origin, 10 degrees wide."""
    import stage

    return stage.look_at((0.0, 0.0, distance), fov_deg=10, width=256, height=256)


def truth(P: int, seed: int = 0, alpha=(0.1, 0.6)):
    """Random true parameters (rho_d [P, 3], F0 [P, 1], alpha [P, 1]); ``alpha`` a (lo, hi) range or values."""
    import numpy as np

    rng = np.random.default_rng(seed)
    rho = rng.uniform(0.1, 0.8, (P, 3))
    f0 = rng.uniform(0.02, 0.08, (P, 1))
    a = rng.uniform(alpha[0], alpha[1], (P, 1)) if isinstance(alpha, tuple) else np.asarray(alpha).reshape(P, 1)
    return rho, f0, a


def capture_of(surface, rig, cam, rho, f0, alpha, noise: float, seed: int = 2, shadow: float = 0.0):
    """Simulated OLAT capture (no occluders: every light in front of a sample is visible),
    radiance x (1 + noise N(0,1)); ``shadow``: that fraction of valid observations zeroed
    but left in the mask (unmasked cast shadows)."""
    import jax.numpy as jnp
    import numpy as np

    import brdf
    import stage

    P, L = surface.num_samples, rig.num_lights
    mat = brdf.lambert_ggx(jnp.asarray(rho, jnp.float32), jnp.asarray(f0, jnp.float32), jnp.asarray(alpha, jnp.float32))
    cap = stage.simulate(surface, rig, [cam], mat, np.ones((P, L), bool), np.ones((1, P), bool))
    rng = np.random.default_rng(seed)
    rad = np.asarray(cap.radiance, np.float32)
    if noise > 0:
        rad = rad * (1 + noise * rng.standard_normal(rad.shape)).astype(np.float32)
    if shadow > 0:
        hit = np.asarray(cap.mask) & (rng.uniform(size=cap.mask.shape) < shadow)
        rad = np.where(hit[..., None], 0.0, rad).astype(np.float32)
    return stage.Capture(jnp.asarray(rad), cap.mask, cap.rig, cap.cameras)


def errors(f: relight.Fit, rho, alpha, normal):
    """Per-sample errors: relative albedo (mean over RGB), relative roughness, normal angle (deg)."""
    import numpy as np

    e_rho = np.mean(np.abs(np.asarray(f.rho_d) - rho) / rho, axis=1)
    e_alpha = np.abs(np.asarray(f.alpha)[:, 0] - alpha[:, 0]) / alpha[:, 0]
    c = np.sum(np.asarray(f.normal, np.float64) * np.asarray(normal, np.float64), 1)
    e_n = np.rad2deg(np.arccos(np.clip(c, -1, 1)))
    return e_rho, e_alpha, e_n


def fit_scene(texels: int, noise: float = 0.01):
    """The scene of scripts/bench_fit.py (built inline there): ``texels`` samples of a 50 mm sphere's
    camera-facing part, their shading normals tilted 5 degrees, under the Light Stage X seen from
    ``front_camera()``, with random true parameters (``truth``) and radiance x (1 + noise N(0, 1)).

    Returns:
        (capture, geometric surface (the fit's start frame), true surface, (rho_d, F0, alpha) truth).
    """
    import stage

    geo = sphere_surface(texels, seed=0)
    true_surf = tilt(geo, 5.0, seed=1)
    rho, f0, alpha = truth(texels, seed=3)
    cap = capture_of(true_surf, stage.light_stage_x(), front_camera(), rho, f0, alpha, noise, seed=4)
    return cap, geo, true_surf, (rho, f0, alpha)


def uv_sphere(radius=50.0, n_lat=48, n_lon=96, center=(0.0, 0.0, 0.0)):
    """``stage.uv_sphere``, imported on use (this module loads no JAX at import)."""
    import stage

    return stage.uv_sphere(radius, n_lat, n_lon, center)


# --------------------------------------------------------------------------- texel captures of the memory benchmarks


def texel_sphere_capture(res: int):
    """(capture, surface) of a GGX sphere seen from +z under stage.geodesic_dome(2), at ``res`` texels."""
    import jax.numpy as jnp
    import numpy as np

    import brdf
    import stage

    mesh = uv_sphere(radius=50.0, n_lat=32, n_lon=64)
    surface = stage.texel_samples(mesh, res)
    rig = stage.geodesic_dome(2)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=10, width=256, height=256)
    lv = stage.light_visibility(mesh, surface, rig)
    cv = stage.camera_visibility(mesh, surface, [cam])
    keep = np.nonzero(cv[0] & (np.asarray(surface.position)[:, 2] > 15.0))[0]
    surface = surface.subset(keep)
    n = surface.num_samples
    rng = np.random.default_rng(0)
    rho, f0, alpha = (jnp.asarray(rng.uniform(lo, hi, (n, k)), jnp.float32)
                      for lo, hi, k in ((0.1, 0.8, 3), (0.02, 0.08, 1), (0.15, 0.6, 1)))
    cap = stage.simulate(surface, rig, [cam], brdf.lambert_ggx(rho, f0, alpha), lv[keep], cv[:, keep])
    return cap, surface


def tiled(cap, surface, n: int):
    """The capture and surface with their samples repeated (cyclically) to ``n``."""
    import numpy as np

    import stage

    idx = np.resize(np.arange(surface.num_samples), n)
    return (stage.Capture(cap.radiance[:, :, idx], cap.mask[:, :, idx], cap.rig, cap.cameras),
            surface.subset(idx))


_SURFACE = ("position", "normal", "tangent", "bitangent", "uv", "area", "texel_index", "face")


def save_surface(path: Path, surface) -> None:
    """Write a ``stage.Surface`` as one .npz (``load_surface`` reads it)."""
    import numpy as np

    np.savez(path, resolution=np.asarray(surface.resolution), **{k: np.asarray(getattr(surface, k)) for k in _SURFACE})


def load_surface(path: Path) -> stage.Surface:
    """Read a ``stage.Surface`` written by ``save_surface``."""
    import jax.numpy as jnp
    import numpy as np

    import stage

    z = np.load(path)
    return stage.Surface(**{k: jnp.asarray(z[k]) for k in _SURFACE}, resolution=tuple(int(r) for r in z["resolution"]))


# --------------------------------------------------------------------------- inputs of the speed benchmarks

# The conductor of the BRDF speed benchmarks (scripts/bench_brdf.py, bench_device.py): per-channel eta and k.
ETA = [0.2, 0.9, 1.1]
K = [3.9, 2.4, 2.2]


def ggx_conductor(alpha: float):
    """``brdf.Microfacet(GGX(alpha), ConductorFresnel(ETA, K), "smith")`` in float32, one model for every pair."""
    import jax.numpy as jnp

    import brdf

    return brdf.Microfacet(brdf.GGX(jnp.float32(alpha)),
                           brdf.ConductorFresnel(jnp.asarray([ETA], jnp.float32), jnp.asarray([K], jnp.float32)),
                           "smith")


def random_pairs(n: int, seed: int = 0):
    """n pairs of float32 unit vectors over the upper hemisphere, [n, 3] each (NumPy)."""
    import numpy as np

    rng = np.random.default_rng(seed)

    def dirs():
        z = rng.random(n)
        phi = 2 * np.pi * rng.random(n)
        r = np.sqrt(1 - z * z)
        return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1).astype(np.float32)

    return dirs(), dirs()


def random_olat_stack(key, lights: int, samples: int, channels: int, dtype):
    """A light-major OLAT stack [L, P, C] of U(0, 1) values made in JAX on the default device (no host copy)."""
    import jax

    # One light at a time inside lax.map: peak memory is the stack itself,
    # not the stack plus the random bits of all of it.
    keys = jax.random.split(key, lights)
    gen = jax.jit(lambda ks: jax.lax.map(lambda k: jax.random.uniform(k, (samples, channels), dtype), ks))
    return gen(keys).block_until_ready()


def uniform_lambert_ggx(P: int):
    """``brdf.lambert_ggx`` with rho_d 0.5, F0 0.028, alpha 0.35 for each of P samples (float32)."""
    import jax.numpy as jnp

    import brdf

    f = lambda v, c: jnp.full((P, c), v, jnp.float32)  # noqa: E731
    return brdf.lambert_ggx(f(0.5, 3), f(0.028, 1), f(0.35, 1))


def head_scene(resolution: int):
    """(mesh, surface, rig, camera) of the simulator benchmarks: the bundled head scan's texels on a
    ``resolution``^2 grid, the Light Stage X, a 512 x 512 camera 1.3 m in front (11 degrees wide)."""
    import stage

    mesh = stage.load_head()
    surface = stage.texel_samples(mesh, resolution)
    camera = stage.look_at((0.0, 0.0, 1300.0), fov_deg=11.0, width=512, height=512)
    return mesh, surface, stage.light_stage_x(), camera
