"""Where a fit's time goes: per-texel cost of one forward evaluation of the
reference model (``relight.fitting.predict_radiance``: ``stage.reflected_radiance``
of brdf Modules), its forward-mode Jacobian, the solver's structured residual +
Jacobian (``relight.fitting.residual_and_jacobian``, brdf's component-major
kernels) with the normal equations it feeds, and Optimistix Levenberg-Marquardt
(``relight.fitting.solve_samples``) at 1 and 20 steps (per texel and per
texel-step), for Lambert + GGX + normal on 192 observations x RGB (one chunk
of 256 texels, float32, compile excluded; the best of ``--repeat`` timings,
so a loaded machine reads less noisy).

    python scripts/profile_fit_step.py [--repeat 5]
"""

import time

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from _common import parser

from relight.fitting import (
    Layout,
    NormalLevenbergMarquardt,
    Observations,
    SPDCholesky,
    predict_radiance,
    residual_and_jacobian,
    solve_samples,
)
from relight.materials import GGX

PC, N = 256, 192  # texels per chunk, observations per texel


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _best(fn, args, repeat):
    """Seconds of the fastest of ``repeat`` calls (after one that compiles) and the last output."""
    out = jax.block_until_ready(fn(*args))
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        out = jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return best, out


def main():
    ap = parser(__doc__)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    wi = _unit(rng.normal(size=(PC, N, 3)))
    wi[..., 2] = np.abs(wi[..., 2])
    wo = np.broadcast_to(_unit(np.array([0.1, 0.0, 1.0])), (PC, N, 3)).copy()
    obs = rng.uniform(0.01, 0.5, (PC, N, 3)).astype(np.float32)
    w = np.ones_like(obs)
    irr = np.ones_like(obs)
    wi, wo = wi.astype(np.float32), wo.astype(np.float32)
    lay = Layout(GGX, True, 0.07)
    u0 = jnp.zeros((PC, lay.size), jnp.float32)

    def predict(u, a, b, c):
        return predict_radiance(u, lay, a, b, c)

    def normal_eq(u, *a):  # what a Gauss-Newton step consumes: J^T J and J^T r
        r, J, _ = residual_and_jacobian(u, *a, lay, 0.02)
        return J.T @ J, J.T @ r

    def cm(x):  # component-major [Pc, 3, N]
        return jnp.swapaxes(jnp.asarray(x), 1, 2)

    rows = (("predict (reference)", jax.jit(jax.vmap(predict)), (u0, wi, wo, irr)),
            ("jacfwd of predict", jax.jit(jax.vmap(lambda u, *a: jax.jacfwd(predict)(u, *a))), (u0, wi, wo, irr)),
            ("residual_and_jacobian -> J^T J, J^T r", jax.jit(jax.vmap(normal_eq)),
             (u0, cm(obs), cm(w), cm(wi), cm(wo), cm(irr))))
    for name, fn, a in rows:
        t, _ = _best(fn, a, args.repeat)
        print(f"{name}: {t / PC * 1e6:.1f} us/texel")
    data = Observations(*(jnp.asarray(x) for x in (obs, w, wi, wo, irr)))
    # Tolerances that never stop a solve early, so every texel takes max_steps.
    solvers = (("NormalLevenbergMarquardt", NormalLevenbergMarquardt(rtol=1e-12, atol=1e-12)),
               ("optx.LevenbergMarquardt", optx.LevenbergMarquardt(rtol=1e-12, atol=1e-12,
                                                                   linear_solver=lx.Normal(SPDCholesky()))))
    for name, solver in solvers:
        for ms in (1, 20):
            def solve(u, obs, ms=ms, solver=solver):
                return solve_samples(u, obs, lay, solver=solver, max_steps=ms, cauchy=0.1)

            t, out = _best(solve, (u0, data), max(1, args.repeat // 2))
            steps = float(np.mean(np.asarray(out[3])))
            print(f"{name} max_steps {ms}: {t / PC * 1e3:.3f} ms/texel, {t / PC / steps * 1e6:.1f} "
                  f"us/texel-step (mean steps {steps:.1f}, final rms {float(np.mean(np.asarray(out[1]))):.5f})")


if __name__ == "__main__":
    main()
