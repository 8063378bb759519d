"""Benchmark the GGX conductor model against Mitsuba 3, and run the full
stability sweep.

Speed (default): evaluates ``Microfacet(GGX(alpha), ConductorFresnel(eta, k))`` on
4M random direction pairs (float32) with the public API under ``jax.jit``, and
Mitsuba 3's ``roughconductor`` (distribution ggx, same parameters) on the same
pairs with its vectorised ``llvm_ad_rgb`` variant, alternating runs in one
process. Also the same model as one single-channel model per colour channel
on structure-of-arrays [3, N] inputs (the layout Mitsuba is given; see
``soa_variant``). Prints evaluations per second for all and the ratios (ours / Mitsuba),
the number of XLA fusions in our compiled kernel, and the largest relative
difference between the two results.

    python scripts/bench_brdf.py                       # 4M pairs, 5 repeats
    python scripts/bench_brdf.py --pairs 1048576 --repeats 3
    python scripts/bench_brdf.py --sweep 1000000       # stability sweep, all models

Mitsuba's LLVM backend needs libLLVM >= 16. On Debian 12 without root:
    apt-get download libllvm19 && dpkg -x libllvm19_*.deb /tmp/llvm19
    export DRJIT_LIBLLVM_PATH=/tmp/llvm19/usr/lib/x86_64-linux-gnu/libLLVM.so.19.1
Without it (or without mitsuba) only our numbers are printed.
"""

from __future__ import annotations

import os
import re
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from _common import ETA, K, ggx_conductor, parser, random_pairs

import brdf


def fusion_count(compiled) -> int:
    return len(re.findall(r"= \S+ fusion\(", compiled.as_text()))


def ours_variants(alpha: float, n: int):
    """name -> function of (wi, wo). All evaluate the same model."""
    model = ggx_conductor(alpha)
    out = {}
    out["jax (public API, jit)"] = lambda wi, wo: model(wi, wo)

    chunk = 1 << 16
    if n % chunk == 0:

        def chunked(wi, wo):
            # lax.map over chunks small enough to keep every intermediate in cache
            pairs = (wi.reshape(-1, chunk, 3), wo.reshape(-1, chunk, 3))
            return jax.lax.map(lambda p: model(p[0], p[1]), pairs).reshape(-1, 3)

        out[f"jax (lax.map, {chunk} per chunk)"] = chunked

    # One material, vmapped over the minor axis of [3, N] (structure-of-arrays)
    # inputs: every intermediate is then a contiguous [1, N] row instead of an
    # [N, 1] column of an [N, 3] array. The transposes are part of the timing.
    single = brdf.Microfacet(
        brdf.GGX(jnp.float32(alpha)),
        brdf.ConductorFresnel(jnp.asarray(ETA, jnp.float32), jnp.asarray(K, jnp.float32)),
        "smith",
    )
    out["jax (vmap over [3, N] layout)"] = lambda wi, wo: jax.vmap(single, in_axes=(1, 1), out_axes=1)(wi.T, wo.T).T
    return out


SOA_NAME = "jax (one model per channel, [3, N] SoA in)"


def soa_variant(alpha: float):
    """The same model on structure-of-arrays inputs [3, N] -> [3, N], given in that
    layout (as Mitsuba's are: the transposes are outside the timing for both), with
    one single-channel model per colour channel, each vmapped over the minor axis.
    Every intermediate is then a contiguous [N] row of the same shape: no [N, 1]
    against [N, 3] broadcast, which is what kept XLA from fusing the divides and
    square roots (docs/brdf.md, Speed). XLA CSEs the shared D and G terms."""
    models = [
        brdf.Microfacet(brdf.GGX(jnp.float32(alpha)), brdf.ConductorFresnel(jnp.float32(e), jnp.float32(k)), "smith")
        for e, k in zip(ETA, K, strict=False)
    ]

    def soa(wi_t, wo_t):
        return jnp.concatenate([jax.vmap(m, in_axes=(1, 1), out_axes=1)(wi_t, wo_t) for m in models], 0)

    return soa


# The same model as a hand-written C++ loop behind an XLA FFI custom call: an
# experiment measuring what XLA's CPU code leaves on the table (docs/brdf.md).
# Compiled with g++ -O3 -march=native -fno-math-errno -fno-trapping-math (IEEE
# semantics kept; the last two flags let GCC vectorise sqrt and the selects).
FFI_SOURCE = r"""
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <thread>
#include <vector>
#include "xla/ffi/api/ffi.h"
namespace ffi = xla::ffi;

static inline float fres(float c, float eta, float k) {
  float c2 = c * c, s2 = 1.0f - c2;
  float t1 = eta * eta - k * k - s2;
  float a2pb2 = std::sqrt(t1 * t1 + 4.0f * eta * eta * k * k);
  float a = std::sqrt(std::max(0.5f * (a2pb2 + t1), 0.0f));
  float term1 = a2pb2 + c2, term2 = 2.0f * a * c;
  float rs = (term1 - term2) / (term1 + term2);
  float term3 = a2pb2 * c2 + s2 * s2, term4 = term2 * s2;
  float rp = rs * (term3 - term4) / (term3 + term4);
  return 0.5f * (rs + rp);
}

static void run(const float* __restrict wi, const float* __restrict wo, float alpha, const float* __restrict eta,
                const float* __restrict k, float* __restrict out, int64_t b, int64_t e) {
  const float a2 = alpha * alpha, inv_pi_a2 = 1.0f / (3.14159265358979f * a2);
  const float e0 = eta[0], e1 = eta[1], e2 = eta[2], k0 = k[0], k1 = k[1], k2 = k[2];
#pragma omp simd
  for (int64_t i = b; i < e; ++i) {
    float xi = wi[3 * i], yi = wi[3 * i + 1], zi = wi[3 * i + 2];
    float xo = wo[3 * i], yo = wo[3 * i + 1], zo = wo[3 * i + 2];
    float hx = xi + xo, hy = yi + yo, hz = zi + zo;
    float n2 = hx * hx + hy * hy + hz * hz;
    float inv = 1.0f / std::sqrt(std::max(n2, 1e-30f));
    hx *= inv; hy *= inv; hz *= inv;
    float cd = xi * hx + yi * hy + zi * hz;
    float t = (hx * hx + hy * hy) / a2 + hz * hz;
    float d = inv_pi_a2 / (t * t);
    float gi = 2.0f / (zi + std::sqrt(a2 * (xi * xi + yi * yi) + zi * zi));
    float go = 2.0f / (zo + std::sqrt(a2 * (xo * xo + yo * yo) + zo * zo));
    bool active = (zi > 0.0f) & (zo > 0.0f);
    float dg = active ? 0.25f * d * gi * go : 0.0f;  // a select: inactive lanes may hold inf
    cd = std::min(std::max(cd, 0.0f), 1.0f);
    out[3 * i] = dg * fres(cd, e0, k0);
    out[3 * i + 1] = dg * fres(cd, e1, k1);
    out[3 * i + 2] = dg * fres(cd, e2, k2);
  }
}

static ffi::Error Impl(ffi::Buffer<ffi::F32> wi, ffi::Buffer<ffi::F32> wo, ffi::Buffer<ffi::F32> eta,
                       ffi::Buffer<ffi::F32> k, float alpha, ffi::ResultBuffer<ffi::F32> out) {
  int64_t n = wi.element_count() / 3;
  unsigned nt = std::max(1u, std::thread::hardware_concurrency());
  if (n < 65536) nt = 1;
  std::vector<std::thread> th;
  int64_t step = (n + nt - 1) / nt;
  for (unsigned t = 0; t < nt; ++t) {
    int64_t b = t * step, e = std::min<int64_t>(n, b + step);
    if (b >= e) break;
    th.emplace_back(run, wi.typed_data(), wo.typed_data(), alpha, eta.typed_data(), k.typed_data(),
                    out->typed_data(), b, e);
  }
  for (auto& x : th) x.join();
  return ffi::Error::Success();
}

XLA_FFI_DEFINE_HANDLER_SYMBOL(GgxConductorF32, Impl,
                              ffi::Ffi::Bind()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Attr<float>("alpha")
                                  .Ret<ffi::Buffer<ffi::F32>>());
"""


def ffi_variant(alpha: float):
    """A jitted function evaluating the C++ kernel through jax.ffi, or None with a reason."""
    import ctypes
    import shutil
    import subprocess
    import tempfile

    if shutil.which("g++") is None:
        return None, "no g++"
    d = tempfile.mkdtemp(prefix="bench_brdf_ffi_")
    src, lib = os.path.join(d, "ggx.cc"), os.path.join(d, "libggx.so")
    with open(src, "w") as f:
        f.write(FFI_SOURCE)
    cmd = ["g++", "-O3", "-march=native", "-fno-math-errno", "-fno-trapping-math", "-shared", "-fPIC",
           "-std=c++17", f"-I{jax.ffi.include_dir()}", "-o", lib, src, "-lpthread"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        return None, f"g++ failed: {r.stderr[-500:]}"
    handle = ctypes.cdll.LoadLibrary(lib)
    jax.ffi.register_ffi_target("bench_brdf_ggx_conductor_f32", jax.ffi.pycapsule(handle.GgxConductorF32),
                                platform="cpu")
    eta, k = jnp.asarray(ETA, jnp.float32), jnp.asarray(K, jnp.float32)

    def call(wi, wo):
        out = jax.ShapeDtypeStruct(wi.shape, jnp.float32)
        return jax.ffi.ffi_call("bench_brdf_ggx_conductor_f32", out)(wi, wo, eta, k, alpha=np.float32(alpha))

    return call, None


def mitsuba_eval_fn(alpha: float, wi: np.ndarray, wo: np.ndarray):
    """A function that evaluates Mitsuba's roughconductor on the pairs and returns
    f_r (cosine divided out), or None with a reason."""
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError:
        return None, "mitsuba not installed (pip install mitsuba)"
    if "llvm_ad_rgb" not in mi.variants():
        return None, "mitsuba has no llvm_ad_rgb variant"
    try:
        mi.set_variant("llvm_ad_rgb")
    except Exception as e:  # libLLVM not found
        return None, f"llvm_ad_rgb unavailable ({e}); set DRJIT_LIBLLVM_PATH"
    bsdf = mi.load_dict(
        {"type": "roughconductor", "distribution": "ggx", "alpha_u": alpha, "alpha_v": alpha,
         "eta": {"type": "rgb", "value": ETA}, "k": {"type": "rgb", "value": K}}
    )
    n = wi.shape[0]
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(np.ascontiguousarray(wi.T))
    wo_m = mi.Vector3f(np.ascontiguousarray(wo.T))
    ctx = mi.BSDFContext()
    dr.eval(si, wo_m)

    def run():
        v = bsdf.eval(ctx, si, wo_m)
        dr.eval(v)
        dr.sync_thread()
        return v

    def to_numpy(v):
        return np.asarray(v).T / wo[:, 2:3]

    return (run, to_numpy, dr.thread_count()), None


def bench(args) -> int:
    n = args.pairs
    wi_np, wo_np = random_pairs(n, args.seed)
    wi, wo = jnp.asarray(wi_np), jnp.asarray(wo_np)
    print(f"{n} direction pairs, float32, GGX alpha={args.alpha}, conductor eta={ETA} k={K}")
    print(f"jax {jax.__version__}, devices {jax.devices()}, XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r}")
    timers = {}
    results = {}
    for name, fn in ours_variants(args.alpha, n).items():
        t0 = time.perf_counter()
        compiled = jax.jit(fn).lower(wi, wo).compile()
        compile_s = time.perf_counter() - t0
        results[name] = np.asarray(compiled(wi, wo))
        timers[name] = lambda c=compiled: jax.block_until_ready(c(wi, wo))
        print(f"  {name}: {fusion_count(compiled)} fusions, compiled in {compile_s:.1f} s")
        if args.hlo:
            print(compiled.as_text())
    # structure-of-arrays inputs, prepared outside the timing as Mitsuba's are
    wi_t, wo_t = jnp.asarray(np.ascontiguousarray(wi_np.T)), jnp.asarray(np.ascontiguousarray(wo_np.T))
    compiled = jax.jit(soa_variant(args.alpha)).lower(wi_t, wo_t).compile()
    results[SOA_NAME] = np.asarray(compiled(wi_t, wo_t)).T
    timers[SOA_NAME] = lambda c=compiled: jax.block_until_ready(c(wi_t, wo_t))
    print(f"  {SOA_NAME}: {fusion_count(compiled)} fusions")
    if args.hlo:
        print(compiled.as_text())
    if not args.no_ffi:
        call, why = ffi_variant(args.alpha)
        name = "C++ loop via jax.ffi (experiment)"
        if call is None:
            print(f"  {name}: skipped: {why}")
        else:
            compiled = jax.jit(call).lower(wi, wo).compile()
            results[name] = np.asarray(compiled(wi, wo))
            timers[name] = lambda c=compiled: jax.block_until_ready(c(wi, wo))
    mits, why = mitsuba_eval_fn(args.alpha, wi_np, wo_np)
    if mits is None:
        print(f"  Mitsuba: skipped: {why}")
    else:
        run, to_numpy, threads = mits
        results["mitsuba roughconductor (llvm_ad_rgb)"] = to_numpy(run())  # also warms the kernel cache
        timers["mitsuba roughconductor (llvm_ad_rgb)"] = run
        print(f"  Mitsuba {__import__('mitsuba').__version__}, Dr.Jit threads: {threads}")
    times = {k: [] for k in timers}
    for _ in range(args.repeats):  # alternate, so that load changes hit all alike
        for k, f in timers.items():
            t0 = time.perf_counter()
            f()
            times[k].append(time.perf_counter() - t0)
    print(f"\n{'implementation':42s} {'best ms':>9s} {'median ms':>10s} {'M evals/s (best)':>17s}")
    rate = {}
    for k, ts in times.items():
        rate[k] = n / min(ts)
        print(f"{k:42s} {min(ts) * 1e3:9.1f} {np.median(ts) * 1e3:10.1f} {rate[k] / 1e6:17.1f}")
    mk = "mitsuba roughconductor (llvm_ad_rgb)"
    if mk in rate:
        ref = results[mk]
        for k in rate:
            if k == mk:
                continue
            scale = np.maximum(np.abs(ref), 1e-6 * np.abs(ref).max())
            err = np.max(np.abs(results[k] - ref) / scale)
            print(f"ratio {k} / Mitsuba: {rate[k] / rate[mk]:.2f}   (max rel. difference {err:.1e})")
    return 0


def sweep(args) -> int:
    """Stability sweep: every model of brdf.check.example_models over >= N edge-case
    pairs (grazing cos = 1e-7 and 0, wi = wo, mirror, normal incidence) with
    per-pair parameters from the roughness floor to 1, float32 and float64."""
    jax.config.update("jax_enable_x64", True)
    chunk = min(args.chunk, args.sweep)
    n_chunks = -(-args.sweep // chunk)
    failures = 0
    for dtype in (jnp.float32, jnp.float64):
        key = jax.random.PRNGKey(args.seed)
        bad: dict[str, set] = {}
        t0 = time.perf_counter()
        for i in range(n_chunks):
            k1, k2 = jax.random.split(jax.random.fold_in(key, i))
            wi, wo = brdf.check.edge_case_pairs(k1, chunk, dtype)
            for name, model in brdf.check.example_models(k2, chunk, dtype).items():
                report = brdf.check.stability(model, wi, wo, batched=True)
                for what, ok in report.items():
                    if not ok:
                        bad.setdefault(name, set()).add(what)
        n = n_chunks * chunk
        print(f"{jnp.dtype(dtype).name}: {n} pairs x {len(brdf.check.example_models(k2, 2, dtype))} models "
              f"in {time.perf_counter() - t0:.0f} s: " + ("all finite and >= 0" if not bad else f"FAILED {bad}"))
        failures += len(bad)
    return 1 if failures else 0


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--pairs", type=int, default=1 << 22, help="direction pairs (default 4M = 2^22)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--alpha", type=float, default=0.3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--hlo", action="store_true", help="print our compiled HLO")
    ap.add_argument("--no-ffi", action="store_true", help="skip the C++ custom-call experiment")
    ap.add_argument("--sweep", type=int, default=0, help="run the stability sweep over this many pairs instead")
    ap.add_argument("--chunk", type=int, default=1 << 17, help="pairs per sweep chunk")
    args = ap.parse_args(argv)
    return sweep(args) if args.sweep else bench(args)


if __name__ == "__main__":
    sys.exit(main())
