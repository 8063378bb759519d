"""Refine a light rig's calibration from an OLAT capture of a known sphere,
by gradient-based least squares through ``stage.simulate``.

A light stage's nominal calibration drifts: each light's brightness by
10-20%, its position by a few millimetres. Imaging a sphere of known shape and
material under every light, one at a time, pins both down. Here the
"measured" capture is simulated with the true rig (Lambert + GGX sphere,
radius 50 mm, three cameras on a ring); the rig is then recovered from the
perturbed nominal rig by minimising

    sum_{v,l,p,c} m_vlp (L_sim(v, l, p, c; I, x) - L_meas(v, l, p, c))^2

over every light's intensity I_l (as a log gain, one per light) and position
x_l (an offset in mm), with Optimistix's Levenberg-Marquardt (Jacobian by
forward-mode differentiation through ``stage.simulate``; the visibility is
ray-cast once from the nominal rig and held fixed). The residual of light l
depends only on light l's parameters, so the Jacobian is block diagonal and
the normal equations are cheap; the solver does not know it and need not.

Usage:
    python scripts/refine_rig.py [--lights 60] [--noise 0.0] [--seed 0] [--max-steps 40]

Prints the intensity relative error (RMS and max) and that of the irradiance
I/d^2 each light delivers at the centre, the position error in mm (RMS, max,
and split into the part across the light's direction and the radial part,
along which distance and intensity nearly trade off: a 50 mm sphere at 1 m
sees 1/d^2 vary by only +-10%), the capture RMS before and after, and the time.
"""

from __future__ import annotations

import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import lineax as lx  # noqa: E402
import numpy as np  # noqa: E402
import optimistix as optx  # noqa: E402
from _common import parser, uv_sphere  # noqa: E402

import brdf  # noqa: E402
import stage  # noqa: E402


def _f64(tree):
    return jax.tree_util.tree_map(
        lambda x: x.astype(jnp.float64) if hasattr(x, "dtype") and jnp.issubdtype(x.dtype, jnp.floating) else x, tree)


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--lights", type=int, default=60, help="lights on a Fibonacci sphere at 1 m (default 60)")
    ap.add_argument("--texels", type=int, default=16, help="texel grid of the sphere (default 16)")
    ap.add_argument("--intensity-error", type=float, default=0.15,
                    help="std of the per-light gain error (0.15; clipped to +-30%%)")
    ap.add_argument("--position-error", type=float, default=3.0, help="std of each position coordinate's error, mm (3)")
    ap.add_argument("--noise", type=float, default=0.0, help="relative Gaussian noise on the measured capture (0)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-steps", type=int, default=40)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    rng = np.random.default_rng(a.seed)

    # The known target: a white-ish Lambert + GGX sphere, radius 50 mm, at the rig centre.
    mesh = uv_sphere(50.0, 32, 64)
    surf = _f64(stage.texel_samples(mesh, a.texels))
    P = surf.num_samples
    mat = brdf.lambert_ggx(jnp.full((P, 3), 0.8), jnp.full((P, 1), 0.04), jnp.full((P, 1), 0.25))
    cams = tuple(_f64(c) for c in stage.camera_ring(3, 800.0, elevation_mm=150.0, fov_deg=10, width=64, height=64))

    # True rig: near-field lights at 1 m; the nominal (believed) rig is off by
    # a per-light gain and a few mm per coordinate.
    true = _f64(stage.fibonacci_sphere(a.lights, radius_mm=1000.0, near_field=True))
    L = true.num_lights
    gain = np.clip(1.0 + a.intensity_error * rng.standard_normal(L), 0.7, 1.3)
    nominal = stage.Rig(true.position + jnp.asarray(a.position_error * rng.standard_normal((L, 3))),
                        true.intensity / jnp.asarray(gain)[:, None], true.solid_angle, near_field=True)

    cv = stage.camera_visibility(mesh, surf, cams)
    measured = stage.simulate(surf, true, cams, mat, stage.light_visibility(mesh, surf, true), cv, dtype=jnp.float64)
    target = measured.radiance
    if a.noise > 0:
        target = target * (1.0 + a.noise * jnp.asarray(rng.standard_normal(target.shape)))
    lv = stage.light_visibility(mesh, surf, nominal)  # ray-cast once, from what we believe
    weight = measured.mask[..., None].astype(jnp.float64)
    scale = float(jnp.sqrt(jnp.sum(weight * target**2) / jnp.sum(weight)))  # residuals in units of the RMS signal

    def rig_of(y):
        return stage.Rig(nominal.position + y["dpos"], nominal.intensity * jnp.exp(y["log_gain"])[:, None],
                         nominal.solid_angle, near_field=True)

    def residual(y, _):
        cap = stage.simulate(surf, rig_of(y), cams, mat, lv, cv, dtype=jnp.float64)
        return (weight * (cap.radiance - target) / scale).reshape(-1)

    def report(rig):
        r = residual({"log_gain": jnp.log(rig.intensity[:, 0] / nominal.intensity[:, 0]),
                      "dpos": rig.position - nominal.position}, None)
        rel = np.asarray(rig.intensity[:, 0] / true.intensity[:, 0]) - 1.0
        dx = np.asarray(rig.position - true.position)
        radial = np.sum(dx * np.asarray(true.directions), axis=1)
        tangential = np.linalg.norm(dx - radial[:, None] * np.asarray(true.directions), axis=1)
        e_rel = np.asarray(rig.center_irradiance[:, 0] / true.center_irradiance[:, 0]) - 1.0
        rms = float(jnp.sqrt(jnp.sum(r**2) / jnp.sum(weight))) * scale
        rms_ = lambda x: np.sqrt(np.mean(np.square(x)))  # noqa: E731
        return (f"intensity rel. error RMS {rms_(rel):.2e} max {np.abs(rel).max():.2e}; "
                f"I/d^2 at the centre RMS {rms_(e_rel):.2e}\n"
                f"        position error RMS {rms_(np.linalg.norm(dx, axis=1)):.3g} mm "
                f"max {np.linalg.norm(dx, axis=1).max():.3g} mm (tangential RMS {rms_(tangential):.3g} mm, "
                f"radial RMS {rms_(radial):.3g} mm); capture RMS {rms:.3e} ({rms / scale:.2e} of the signal)")

    print(f"sphere: {P} texel samples, {len(cams)} views; rig: {L} near-field lights at 1 m; "
          f"{int(np.asarray(measured.mask).sum())} observations x 3 channels; noise {a.noise:g}")
    print("before:", report(nominal))
    y0 = {"log_gain": jnp.zeros(L), "dpos": jnp.zeros((L, 3))}
    # Normal equations by Cholesky: J^T J is only 4L x 4L (QR of the tall J costs far more).
    solver = optx.LevenbergMarquardt(rtol=1e-10, atol=1e-12, linear_solver=lx.Normal(lx.Cholesky()))
    t1 = time.perf_counter()
    sol = optx.least_squares(residual, solver, y0, max_steps=a.max_steps, throw=False)
    jax.block_until_ready(sol.value)
    t2 = time.perf_counter()
    print("after: ", report(rig_of(sol.value)))
    ok = "converged" if sol.result == optx.RESULTS.successful else "did not converge"
    print(f"solver: Levenberg-Marquardt {ok} in {int(sol.stats['num_steps'])} steps; "
          f"solve {t2 - t1:.1f} s (incl. compilation), total {t2 - t0:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
