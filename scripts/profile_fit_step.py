"""Where a fit's time goes: per-texel cost of one forward evaluation of the
reference model (``_fit_model.predict``), its forward-mode Jacobian, the
solver's structured residual + Jacobian (``_fit_model.residual_and_jacobian``),
and Optimistix Levenberg-Marquardt at 1 and 20 steps, for Lambert + GGX + normal on 192 observations x RGB (one chunk of
256 texels, float32, compile excluded).

    python scripts/profile_fit_step.py
"""
import time

import jax
import jax.numpy as jnp
import numpy as np

from relight.fitting import _driver as _fit, _model as _fit_model
from relight.fitting._model import Layout
Pc, N = 256, 192
rng = np.random.default_rng(0)
def unit(x): return x/np.linalg.norm(x,axis=-1,keepdims=True)
wi = unit(rng.normal(size=(Pc,N,3))); wi[...,2]=np.abs(wi[...,2]); wo = np.broadcast_to(unit(np.array([0.1,0,1.0])),(Pc,N,3)).copy()
obs = rng.uniform(0.01,0.5,(Pc,N,3)).astype(np.float32); w = np.ones_like(obs); h=0*w; irr=np.ones_like(obs)
wi=wi.astype(np.float32); wo=wo.astype(np.float32)
lay = Layout(2, True, 0.07)
u0 = jnp.zeros((Pc, lay.size), jnp.float32)
f = jax.jit(jax.vmap(lambda u,a,b,c: _fit_model.predict(_fit_model.unpack(u,lay),lay,a,b,c)))
J = jax.jit(jax.vmap(lambda u,a,b,c: jax.jacfwd(lambda v: _fit_model.predict(_fit_model.unpack(v,lay),lay,a,b,c))(u)))
T = lambda x: jnp.swapaxes(jnp.asarray(x), 1, 2)
def normal_eq(u, *a):  # what a Gauss-Newton step consumes: J^T J and J^T r
    r, J, _ = _fit_model.residual_and_jacobian(u, *a, lay, 0.02)
    return J.T @ J, J.T @ r
RJ = jax.jit(jax.vmap(normal_eq))
cm = (T(obs), T(w), T(wi), T(wo), T(irr))
for name, fn, a in (("predict (reference)", f, (wi,wo,irr)), ("jacfwd of predict", J, (wi,wo,irr)),
                    ("residual_and_jacobian -> J^T J, J^T r", RJ, cm)):
    jax.block_until_ready(fn(u0,*a)); t=time.perf_counter()
    for _ in range(5): jax.block_until_ready(fn(u0,*a))
    print(name, (time.perf_counter()-t)/5/Pc*1e6, "us/texel")
args = [jnp.asarray(x) for x in (obs,w,h,wi,wo,irr)]
for ms in (1, 20):
    kw = dict(lay=lay, solver="lm", max_steps=ms, rtol=1e-12, atol=1e-12, cauchy=0.1)
    _fit._solve_chunk(u0,*args,**kw)[0].block_until_ready(); t=time.perf_counter()
    out=_fit._solve_chunk(u0,*args,**kw); out[0].block_until_ready()
    print("solve max_steps", ms, (time.perf_counter()-t)/Pc*1e3, "ms/texel", np.mean(np.asarray(out[3])))
