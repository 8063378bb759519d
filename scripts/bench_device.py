"""One prepared benchmark for whatever JAX backend is present: the fit, simulate, relight and BRDF kernels
on the default device and, for scale, on the CPU, with the fraction of the device's peak each reaches.

    python scripts/bench_device.py                   # full sizes: < 8 min on one H100, the CPU column included
    python scripts/bench_device.py --quick           # tiny sizes, a smoke run: < 1 min on 2 CPU cores
    python scripts/bench_device.py --out docs/figures/device_h100.md --kernels fit,relight

Writes one markdown table (default ``docs/figures/device_<device kind>[_quick].md``, atomically) and prints
progress to stderr. The kernels, each run on the device under test (``jax.devices()[--device]``) and then,
unless that device is the CPU, at the CPU sizes on ``jax.devices("cpu")[0]`` (on a CPU-only machine the CPU
column is the same run):

- fit: ``relight.fit(capture, surface, model="ggx", normals=True, loss="cauchy")`` (Lambert + GGX + normal
  per texel) of the sphere scene of scripts/bench_fit.py (``_common.fit_scene``: Light Stage X, 1% noise),
  its solver chunk sized for the device (4096 on an accelerator, 64 on a CPU). Throughput: texels/s.
- simulate: ``stage.simulate_chunks`` (the OLAT forward model, streamed as ``relight simulate`` streams it)
  of the bundled head's camera-facing texels, tiled to the size, Lambert + GGX, under the Light Stage X
  with ray-cast shadows (``stage.light_visibility``, computed once, untimed). Throughput: sample-lights/s.
- relight: ``relight.render.relight_olat`` (image-based relighting, Debevec et al. 2000) of a random
  float32 OLAT stack [346 lights, P, 3] under the light weights (``relight.envmap.light_weights``) of the
  bundled environment map (averaged to 128 x 256 pixels: the weights are not what is timed). Throughput:
  sample-lights/s (each OLAT value read once).
- brdf: the GGX conductor of scripts/bench_brdf.py (``brdf.Microfacet``, Smith masking, RGB conductor
  Fresnel) on random direction pairs. Throughput: evaluations/s.

Timing: one untimed call compiles (compile s: the AOT compile of the one jitted program for relight and
brdf; for fit and simulate, which run many jitted calls, the first call's wall time minus the best timed
one), then SIZES' ``repeat`` calls (fit: ``fit_repeat``), each ended by ``jax.block_until_ready``; the fastest
counts.

Cost: XLA's cost analysis (``jax.jit(f).lower(...).compile().cost_analysis()``: "flops", "bytes accessed") of
a loop-free program doing the kernel's arithmetic, compiled for the same device: XLA counts a loop's body
once, so a kernel that loops (relight_olat's chunk loop, the solver's steps) is costed by its loop-free
equivalent. fit: one texel-step of the solver (``relight.fitting.residual_and_jacobian`` and the normal
equations J^T J, J^T r), times the steps the fit took (``Fit.steps`` summed): a lower bound (the start,
packing, covariances and the lanes of a chunk that finished early are not counted). simulate: the traced
``stage.simulate`` of 256 samples x all lights in one chunk, per sample-light, times those timed. relight:
``sum_l w_l * stack_l`` (a fused multiply-reduce). brdf: the timed program itself.

Peaks (the "which peak" column): for a device in DATASHEET (matched on ``device_kind``), the vendor's FP32
(non-tensor) FLOP/s and memory bandwidth; otherwise (the CPU, an unknown device, a MIG slice) measured in the
same run, before and after the kernels (the larger of the two: a load spike on a shared machine during one
does not lower it): the best read rate of ``jnp.sum`` (and, on a CPU, NumPy's ``add.reduce`` on one thread
and on every core) over arrays of the sizes in ``probe_mib``, caches included, and the best FP32 matmul
(precision "highest", no TF32) FLOP/s. The
fraction is the larger of achieved / peak FLOP/s and achieved / peak bandwidth (the roofline's binding
resource); above 1 would mean the cost count or the peak is wrong.
"""

from __future__ import annotations

import dataclasses
import datetime
import math
import os
import re
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _common import (
    FIG,
    fit_scene,
    ggx_conductor,
    head_scene,
    machine,
    parser,
    random_olat_stack,
    random_pairs,
    uniform_lambert_ggx,
)

import relight
import stage
from relight.envmap import EnvMap, bundled_envmap_path, light_weights, load_envmap
from relight.materials import GGX
from relight.render import relight_olat

KERNELS = ("fit", "simulate", "relight", "brdf")
UNITS = {"fit": "texels", "simulate": "sample-lights", "relight": "sample-lights", "brdf": "evals"}

# Sizes: "device" for an accelerator in full mode, "cpu" for the CPU (the scale column, or the device itself on
# a CPU-only machine), "quick" for both in --quick. fit: texels (chunk: the solver's); head: the head's texel
# grid whose camera-facing texels simulate tiles to `simulate` samples; relight: samples of the 346-light stack;
# brdf: direction pairs; probe_mib / matmul: the sizes of the measured peaks. Per-unit throughputs compare
# across sizes; the full "device" sizes keep every kernel's timed call well above a millisecond on an H100.
SIZES = {
    "device": dict(fit=16384, chunk=4096, head=64, simulate=1 << 18, relight=1 << 20, brdf=1 << 24, repeat=5,
                   fit_repeat=3, probe_mib=(16, 256, 1024), matmul=(2048, 4096)),
    "cpu": dict(fit=2048, chunk=64, head=64, simulate=1 << 15, relight=1 << 18, brdf=1 << 21, repeat=3,
                fit_repeat=2, probe_mib=(1, 4, 16, 64, 256), matmul=(256, 512, 1024)),
    "quick": dict(fit=64, chunk=64, head=32, simulate=1024, relight=2048, brdf=1 << 14, repeat=2, fit_repeat=1,
                  probe_mib=(1, 4, 16), matmul=(256, 512)),
}

# Vendor datasheet peaks, matched on jax.devices()[i].device_kind (a regular expression, case-insensitive; the
# first match wins, so the specific names come first): FP32 non-tensor FLOP/s, memory bandwidth in bytes/s.
# "(?<!G)" keeps Grace Hopper (GH200) out; a MIG slice ("MIG" in the name) is never matched (measured instead).
DATASHEET = (
    # NVIDIA H200 Tensor Core GPU datasheet: H200 SXM FP32 67 TFLOPS, 4.8 TB/s; H200 NVL FP32 60 TFLOPS, 4.8 TB/s.
    (r"(?<!G)H200 NVL", "NVIDIA H200 NVL", 60e12, 4.8e12),
    (r"(?<!G)H200", "NVIDIA H200 SXM", 67e12, 4.8e12),
    # NVIDIA H100 Tensor Core GPU datasheet: H100 SXM FP32 67 TFLOPS, 3.35 TB/s; H100 PCIe 51 TFLOPS, 2 TB/s;
    # H100 NVL 60 TFLOPS, 3.9 TB/s. JAX names the SXM part "NVIDIA H100 80GB HBM3".
    (r"(?<!G)H100 NVL", "NVIDIA H100 NVL", 60e12, 3.9e12),
    (r"(?<!G)H100 PCIe", "NVIDIA H100 PCIe", 51e12, 2.0e12),
    (r"(?<!G)H100", "NVIDIA H100 SXM", 67e12, 3.35e12),
    # NVIDIA A100 Tensor Core GPU datasheet: FP32 19.5 TFLOPS; 80GB SXM 2,039 GB/s, 80GB PCIe 1,935 GB/s,
    # 40GB 1,555 GB/s.
    (r"A100.*80GB.*PCIe", "NVIDIA A100 80GB PCIe", 19.5e12, 1.935e12),
    (r"A100.*80GB", "NVIDIA A100 80GB SXM", 19.5e12, 2.039e12),
    (r"A100", "NVIDIA A100 40GB", 19.5e12, 1.555e12),
    # NVIDIA L40S datasheet: FP32 91.6 TFLOPS, 864 GB/s. L4: FP32 30.3 TFLOPS, 300 GB/s. A10: 31.2 TFLOPS, 600 GB/s.
    (r"L40S", "NVIDIA L40S", 91.6e12, 864e9),
    (r"\bL4\b", "NVIDIA L4", 30.3e12, 300e9),
    (r"\bA10\b", "NVIDIA A10", 31.2e12, 600e9),
    # NVIDIA V100 datasheet: SXM2 FP32 15.7 TFLOPS, PCIe 14 TFLOPS, both 900 GB/s. T4: FP32 8.1 TFLOPS, 320 GB/s.
    (r"V100.*SXM", "NVIDIA V100 SXM2", 15.7e12, 900e9),
    (r"V100", "NVIDIA V100 PCIe", 14e12, 900e9),
    (r"\bT4\b", "NVIDIA T4", 8.1e12, 320e9),
)


@dataclasses.dataclass(frozen=True)
class Peak:
    """A device's peak: FP32 FLOP/s, memory bandwidth (bytes/s), and where the numbers come from."""

    flops: float
    bandwidth: float
    source: str
    largest_read: float = math.nan  # measured: the read rate of the largest probe array alone (bytes/s)


@dataclasses.dataclass(frozen=True)
class Run:
    """One kernel timed on one device: ``count`` units per call, ``flops`` / ``nbytes`` per call (XLA)."""

    kernel: str
    size: str
    device: str
    compile_s: float
    wall_s: float
    count: float
    flops: float
    nbytes: float

    @property
    def throughput(self) -> float:
        return self.count / self.wall_s

    def fraction(self, peak: Peak) -> tuple[float, str]:
        """(the larger of the FLOP/s and bandwidth fractions of ``peak``, which one it is)."""
        f_flop = self.flops / self.wall_s / peak.flops
        f_mem = self.nbytes / self.wall_s / peak.bandwidth
        if not f_mem >= f_flop:  # also when the bandwidth fraction is NaN (no cost from the backend)
            return f_flop, f"FP32 {peak.flops / 1e9:.4g} GFLOP/s"
        return f_mem, f"memory {peak.bandwidth / 1e9:.4g} GB/s"


# --------------------------------------------------------------------------- helpers


def log(msg: str) -> None:
    print(f"[bench_device] {msg}", file=sys.stderr, flush=True)


def put(tree, device):
    """``tree`` with its array leaves on ``device`` (the other leaves, e.g. ints of a Module, kept)."""
    dyn, static = eqx.partition(tree, eqx.is_array)
    return eqx.combine(jax.device_put(dyn, device), static)


def best_of(call, repeat: int) -> float:
    """Seconds of the fastest of ``repeat`` calls of ``call()``, each ended by ``jax.block_until_ready``."""
    best = math.inf
    for _ in range(max(1, repeat)):
        t = time.perf_counter()
        jax.block_until_ready(call())
        best = min(best, time.perf_counter() - t)
    return best


def compile_on(fn, *args):
    """(the compiled ``jax.jit`` of ``fn`` over the array leaves of ``args``, those leaves, compile seconds):
    call it as ``compiled(leaves)``. The arrays' device is the program's."""
    dyn, static = eqx.partition(args, eqx.is_array)
    t = time.perf_counter()
    compiled = jax.jit(lambda d: fn(*eqx.combine(d, static))).lower(dyn).compile()
    return compiled, dyn, time.perf_counter() - t


def xla_cost(compiled) -> tuple[float, float]:
    """(flops, bytes accessed) of a compiled program by XLA's cost analysis; NaN where the backend has none
    (``cost_analysis()`` returns a dict, a list of one dict per program in older JAX, or None)."""
    ca = compiled.cost_analysis()
    if isinstance(ca, (list, tuple)):
        ca = ca[0] if ca else None
    ca = ca or {}
    return float(ca.get("flops", math.nan)), float(ca.get("bytes accessed", math.nan))


def datasheet_peak(device) -> Peak | None:
    """The DATASHEET entry of ``device`` (an accelerator, not a MIG slice), or None."""
    kind = device.device_kind
    if device.platform == "cpu" or "MIG" in kind:
        return None
    for pattern, name, flops, bandwidth in DATASHEET:
        if re.search(pattern, kind, re.IGNORECASE):
            return Peak(flops, bandwidth, f"datasheet: {name}")
    return None


def _numpy_read_rate(nbytes: int, repeat: int) -> float:
    """Bytes/s of NumPy's uint32 ``add.reduce`` (one thread, and split over every core) on ``nbytes``."""
    words = np.ones(nbytes // 4, np.uint32)
    parts = np.array_split(words, os.cpu_count() or 1)
    with ThreadPoolExecutor(len(parts)) as pool:
        calls = (lambda: np.add.reduce(words, dtype=np.uint32),
                 lambda: list(pool.map(lambda p: np.add.reduce(p, dtype=np.uint32), parts)))
        return max(nbytes / best_of(c, repeat) for c in calls)


def measured_peak(device, sizes: dict) -> Peak:
    """The best read bandwidth and FP32 matmul FLOP/s this run reaches on ``device`` (module docstring)."""
    repeat = 5
    rates = []
    with jax.default_device(device):
        for mib in sizes["probe_mib"]:
            x = jnp.ones(mib * 2**20 // 4, jnp.float32)
            compiled = jax.jit(jnp.sum).lower(x).compile()
            rate = x.nbytes / best_of(lambda c=compiled, x=x: c(x), repeat)
            if device.platform == "cpu":
                rate = max(rate, _numpy_read_rate(x.nbytes, repeat))
            rates.append(rate)
            del x
        flops = []
        for n in sizes["matmul"]:
            a = jnp.ones((n, n), jnp.float32)
            compiled = jax.jit(lambda p, q: jnp.matmul(p, q, precision="highest")).lower(a, a).compile()
            flops.append(2.0 * n**3 / best_of(lambda c=compiled, a=a: c(a, a), repeat))
    probes = "/".join(map(str, sizes["probe_mib"]))
    numpy = " (and NumPy add.reduce)" if device.platform == "cpu" else ""
    return Peak(max(flops), max(rates), f"measured before and after the kernels: best jnp.sum read of {probes} "
                f"MiB{numpy}, best FP32 matmul of n = {'/'.join(map(str, sizes['matmul']))}", rates[-1])


def best_peak(a: Peak, b: Peak) -> Peak:
    """Two measurements of one device's peak combined: the larger of each rate."""
    return Peak(max(a.flops, b.flops), max(a.bandwidth, b.bandwidth), a.source, max(a.largest_read, b.largest_read))


# --------------------------------------------------------------------------- the kernels


def fit_step_cost(capture, surface, device, k: int = 64) -> tuple[float, float]:
    """XLA's (flops, bytes) of one solver step of one texel: ``residual_and_jacobian`` and the normal
    equations, vmapped over ``k`` texels of the capture (the one with the most observations among them, so
    the packed observation count is the fit's), divided by ``k``."""
    n_valid = np.asarray(capture.mask).sum(axis=(0, 1))
    sub = np.arange(min(k, surface.num_samples))
    if int(np.argmax(n_valid)) not in sub:
        sub[-1] = int(np.argmax(n_valid))
    part = stage.Capture(capture.radiance[:, :, sub], capture.mask[:, :, sub], capture.rig, capture.cameras)
    obs = relight.fitting.observations(part, surface.subset(sub))
    layout = relight.fitting.Layout(GGX, True, relight.rig_alpha_floor(capture.rig))
    u0 = jax.device_put(relight.fitting.start_parameters(obs, layout), device)

    def normal_equations(u, y, sw, wi, wo, irr):
        r, J, _ = relight.fitting.residual_and_jacobian(u, y, sw, wi, wo, irr, layout, 0.1)
        return J.T @ J, J.T @ r

    def cm(x):  # component-major [k, 3, N], as the solver holds them
        return jnp.swapaxes(jax.device_put(np.asarray(x, np.float32), device), 1, 2)

    args = (u0, cm(obs.radiance), cm(np.sqrt(obs.weight)), cm(obs.wi), cm(obs.wo), cm(obs.irradiance))
    flops, nbytes = xla_cost(jax.jit(jax.vmap(normal_equations)).lower(*args).compile())
    return flops / len(sub), nbytes / len(sub)


def bench_fit(device, sizes: dict, context: dict) -> Run:
    P, chunk = sizes["fit"], sizes["chunk"]
    capture, surface, _, _ = fit_scene(P)
    kw = dict(model="ggx", normals=True, loss="cauchy",
              options=relight.fitting.FitOptions(chunk=chunk, devices=[device]))
    t = time.perf_counter()
    fit = relight.fit(capture, surface, **kw)
    jax.block_until_ready(fit.rho_d)
    first = time.perf_counter() - t
    wall = best_of(lambda: relight.fit(capture, surface, **kw).rho_d, sizes["fit_repeat"])
    flops, nbytes = fit_step_cost(capture, surface, device)
    steps = float(np.sum(np.asarray(fit.steps)))
    size = f"{P} texels x {capture.rig.num_lights} lights, chunk {chunk}, {steps / P:.1f} steps/texel"
    return Run("fit", size, str(device), max(first - wall, 0.0), wall, P, flops * steps, nbytes * steps)


def head_visibility(resolution: int) -> dict:
    """The head scene with its camera-facing texels and their ray-cast visibility (NumPy; computed once)."""
    mesh, surface, rig, camera = head_scene(resolution)
    lv = np.asarray(stage.light_visibility(mesh, surface, rig), bool)
    cv = np.asarray(stage.camera_visibility(mesh, surface, [camera]), bool)
    seen = np.nonzero(cv[0])[0]
    return dict(surface=surface, rig=rig, camera=camera, lv=lv, cv=cv, seen=seen)


def bench_simulate(device, sizes: dict, context: dict) -> Run:
    key = ("head", sizes["head"])
    if key not in context:
        context[key] = head_visibility(sizes["head"])
    head = context[key]
    P = sizes["simulate"]
    idx = np.resize(head["seen"], P)
    rig, camera = put(head["rig"], device), put(head["camera"], device)
    L = rig.num_lights
    surface, material = put(head["surface"].subset(idx), device), put(uniform_lambert_ggx(P), device)
    lv, cv = head["lv"][idx], head["cv"][:, idx]

    def run():
        for _, _, _, radiance, _ in stage.simulate_chunks(surface, rig, [camera], material, lv, cv):
            jax.block_until_ready(radiance)
        return radiance

    t = time.perf_counter()
    run()
    first = time.perf_counter() - t
    wall = best_of(run, sizes["repeat"])
    # Cost per sample-light: the traced simulate of p samples x every light as one chunk (no loop, no padding).
    p = min(P, 256)

    def traced(s, m):
        return stage.simulate(s, rig, [camera], m, lv[:p], cv[:, :p], light_chunk=L).radiance

    compiled, _, _ = compile_on(traced, put(head["surface"].subset(idx[:p]), device),
                                put(uniform_lambert_ggx(p), device))
    flops, nbytes = (c * P / p for c in xla_cost(compiled))
    size = f"{P} samples x {L} lights (head texels tiled, shadows)"
    return Run("simulate", size, str(device), max(first - wall, 0.0), wall, P * L, flops, nbytes)


def bundled_envmap_4x() -> EnvMap:
    """The bundled environment map averaged over 4 x 4 pixel blocks (128 x 256 for its 512 x 1024): the light
    weights of 346 lights barely change (their sum by 1e-4), and computing them takes a second, not ten."""
    r = np.asarray(load_envmap(bundled_envmap_path()).radiance, np.float32)
    H, W, C = (r.shape[0] // 4) * 4, (r.shape[1] // 4) * 4, r.shape[2]
    return EnvMap(jnp.asarray(r[:H, :W].reshape(H // 4, 4, W // 4, 4, C).mean(axis=(1, 3))))


def bench_relight(device, sizes: dict, context: dict) -> Run:
    rig = stage.light_stage_x()
    L, P, C = rig.num_lights, sizes["relight"], 3
    pos = np.asarray(rig.position, np.float64)
    irr = np.broadcast_to(np.asarray(rig.center_irradiance, np.float64).reshape(L, -1), (L, C))
    if "weights" not in context:  # the same for every device
        w = light_weights(bundled_envmap_4x(), pos / np.linalg.norm(pos, axis=1, keepdims=True), irr)
        context["weights"] = np.asarray(w, np.float32)
    weights = jax.device_put(context["weights"], device)
    with jax.default_device(device):
        stack = random_olat_stack(jax.random.PRNGKey(0), L, P, C, jnp.float32)
    compiled, dyn, compile_s = compile_on(relight_olat, stack, weights)
    wall = best_of(lambda: compiled(dyn), sizes["repeat"])
    equivalent, _, _ = compile_on(lambda s, w: jnp.sum(s * w[:, None, :], axis=0), stack, weights)
    flops, nbytes = xla_cost(equivalent)
    size = f"{L} x {P} x {C} float32 stack ({stack.nbytes / 1e9:.3g} GB)"
    return Run("relight", size, str(device), compile_s, wall, L * P, flops, nbytes)


def bench_brdf(device, sizes: dict, context: dict) -> Run:
    n = sizes["brdf"]
    wi, wo = (jax.device_put(x, device) for x in random_pairs(n))
    compiled, dyn, compile_s = compile_on(lambda m, a, b: m(a, b), put(ggx_conductor(0.3), device), wi, wo)
    wall = best_of(lambda: compiled(dyn), sizes["repeat"])
    flops, nbytes = xla_cost(compiled)
    return Run("brdf", f"{n} pairs, GGX conductor RGB", str(device), compile_s, wall, n, flops, nbytes)


BENCH = {"fit": bench_fit, "simulate": bench_simulate, "relight": bench_relight, "brdf": bench_brdf}


def run_kernel(name: str, device, sizes: dict, context: dict) -> Run:
    """``BENCH[name]`` on ``device`` (its default device too, for the arrays the library makes), logged."""
    log(f"{name} on {device} ...")
    with jax.default_device(device):
        r = BENCH[name](device, sizes, context)
    log(f"{name} on {device}: {r.size}; compile {r.compile_s:.1f} s, best {r.wall_s:.4g} s, "
        f"{r.throughput:.4g} {UNITS[name]}/s, {_g(r.flops / r.wall_s / 1e9)} GFLOP/s, "
        f"{_g(r.nbytes / r.wall_s / 1e9)} GB/s")
    return r


# --------------------------------------------------------------------------- the table


def _g(x: float) -> str:
    return "n/a" if not math.isfinite(x) else f"{x:.4g}"


def table(runs: list[Run], cpu_runs: dict[str, Run] | None, peak: Peak) -> list[str]:
    """The main table: one row per kernel on the device; the CPU column from ``cpu_runs`` (None: same run)."""
    lines = ["| kernel | size | backend device | compile s | wall s | throughput | CPU throughput | ratio | "
             "achieved GFLOP/s | achieved GB/s | fraction of peak | which peak |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        unit = UNITS[r.kernel]
        c = r if cpu_runs is None else cpu_runs[r.kernel]
        cpu = f"{c.throughput:.4g} {unit}/s" + (" (same run)" if cpu_runs is None else "")
        frac, which = r.fraction(peak)
        lines.append(f"| {r.kernel} | {r.size} | {r.device} | {r.compile_s:.1f} | {r.wall_s:.4g} | "
                     f"{r.throughput:.4g} {unit}/s | {cpu} | {r.throughput / c.throughput:.3g} | "
                     f"{_g(r.flops / r.wall_s / 1e9)} | {_g(r.nbytes / r.wall_s / 1e9)} | {_g(frac)} | {which} |")
    return lines


def cpu_table(cpu_runs: dict[str, Run], peak: Peak) -> list[str]:
    """The CPU scale runs (only when the device under test is not the CPU)."""
    lines = ["| kernel | size | CPU device | compile s | wall s | throughput | achieved GFLOP/s | achieved GB/s | "
             "fraction of peak | which peak |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in cpu_runs.values():
        frac, which = r.fraction(peak)
        lines.append(f"| {r.kernel} | {r.size} | {r.device} | {r.compile_s:.1f} | {r.wall_s:.4g} | "
                     f"{r.throughput:.4g} {UNITS[r.kernel]}/s | {_g(r.flops / r.wall_s / 1e9)} | "
                     f"{_g(r.nbytes / r.wall_s / 1e9)} | {_g(frac)} | {which} |")
    return lines


def _peak_line(label: str, peak: Peak) -> str:
    largest = ("" if not math.isfinite(peak.largest_read)
               else f"; the largest array alone: {peak.largest_read / 1e9:.4g} GB/s")
    return (f"- {label}: FP32 {peak.flops / 1e9:.4g} GFLOP/s, memory {peak.bandwidth / 1e9:.4g} GB/s "
            f"({peak.source}{largest})")


def report(args, device, cpu, runs, cpu_runs, peaks: dict[str, Peak], command: str, load: tuple) -> str:
    separate = cpu_runs is not None
    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC")
    lines = [f"# Device benchmark: {device.device_kind}", "",
             f"`{command}`, {date}{' (quick: tiny sizes, a smoke run, not a measurement)' if args.quick else ''}.",
             "",
             f"Machine: {machine()}, load average {load[0]:.1f} at the start, {load[1]:.1f} at the end (other "
             f"processes share the CPU when it exceeds the cores); device under test {device} "
             f"({device.device_kind}); CPU column: "
             + (f"{cpu}, a separate run at the CPU sizes (second table)." if separate
                else "the same run (the device is the CPU)."), "",
             "Peaks:", _peak_line(f"{device}", peaks["device"])]
    if "device measured" in peaks:
        lines.append(_peak_line(f"{device}, measured in this run (for comparison only)", peaks["device measured"]))
    if separate:
        lines.append(_peak_line(f"{cpu}", peaks["cpu"]))
    lines += ["", *table(runs, cpu_runs, peaks["device"]), ""]
    if separate:
        lines += [f"CPU scale runs ({cpu}):", "", *cpu_table(cpu_runs, peaks["cpu"]), ""]
    lines += ["Columns: compile s = the first call's extra time (one AOT compile for relight and brdf); wall s = "
              "the fastest timed call; throughput = units per call / wall s; ratio = throughput / CPU throughput "
              "(sizes may differ: per-unit rates compare); achieved GFLOP/s and GB/s = XLA's cost analysis of "
              "the kernel (or its loop-free equivalent; fit: a lower bound) / wall s; fraction of peak = the "
              "larger of the two against the peak named (datasheet or measured, above). How each kernel is "
              "timed and costed: the docstring of scripts/bench_device.py.", ""]
    return "\n".join(lines)


def default_out(device, quick: bool) -> Path:
    name = "cpu" if device.platform == "cpu" else re.sub(r"[^a-z0-9]+", "_", device.device_kind.lower()).strip("_")
    return FIG / f"device_{name}{'_quick' if quick else ''}.md"


def main(argv=None) -> int:
    ap = parser(__doc__)
    ap.add_argument("--quick", action="store_true", help="tiny sizes (a smoke run, well under a minute on a CPU)")
    ap.add_argument("--out", help="the markdown file (default docs/figures/device_<device kind>[_quick].md)")
    ap.add_argument("--kernels", default=",".join(KERNELS), help=f"comma list of {', '.join(KERNELS)}")
    ap.add_argument("--device", type=int, default=0, help="which of jax.devices() to test (default 0)")
    args = ap.parse_args(argv)
    kernels = [k.strip() for k in args.kernels.split(",") if k.strip()]
    if not kernels or any(k not in KERNELS for k in kernels):
        ap.error(f"--kernels: a comma list of {', '.join(KERNELS)}, got {args.kernels!r}")
    if not 0 <= args.device < len(jax.devices()):
        ap.error(f"--device: 0 to {len(jax.devices()) - 1} (jax.devices(): {jax.devices()}), got {args.device}")
    try:
        cpu = jax.devices("cpu")[0]
    except RuntimeError as e:
        raise SystemExit(f"bench_device: no CPU backend for the scale column ({e}); "
                         "let JAX see the CPU too, e.g. JAX_PLATFORMS=cuda,cpu") from None
    device = jax.devices()[args.device]
    separate = device != cpu
    dev_sizes = SIZES["quick"] if args.quick else SIZES["device" if device.platform != "cpu" else "cpu"]
    cpu_sizes = SIZES["quick"] if args.quick else SIZES["cpu"]
    out = Path(args.out) if args.out else default_out(device, args.quick)
    t0 = time.perf_counter()
    load0 = os.getloadavg()[0]
    targets = [(device, dev_sizes)] + ([(cpu, cpu_sizes)] if separate else [])
    log(f"device {device} ({device.device_kind}); measuring peaks ...")
    before = [measured_peak(d, s) for d, s in targets]
    context: dict = {}
    runs: list[Run] = []
    cpu_runs: dict[str, Run] = {}
    for name in kernels:
        runs.append(run_kernel(name, device, dev_sizes, context))
        if separate:
            cpu_runs[name] = run_kernel(name, cpu, cpu_sizes, context)
    log("measuring peaks again ...")
    # The best of the two measurements: a load spike on a shared machine during one of them does not lower it.
    measured = [best_peak(a, measured_peak(d, s)) for a, (d, s) in zip(before, targets, strict=True)]
    peaks = {"device": datasheet_peak(device) or measured[0]}
    if peaks["device"] is not measured[0]:
        peaks["device measured"] = measured[0]
    if separate:
        peaks["cpu"] = measured[1]
    command = "python scripts/bench_device.py " + " ".join(sys.argv[1:] if argv is None else argv)
    text = report(args, device, cpu, runs, cpu_runs if separate else None, peaks, command.strip(),
                  (load0, os.getloadavg()[0]))
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, out)
    print(text)
    log(f"wrote {out} in {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
