"""Benchmark the stage simulator: Light Stage X (346 lights) on the bundled head
scan at a texel grid (default 512 x 512).

Prints: the one-off visibility cost (rays/s), shading throughput in
samples x lights per second (through ``stage.simulate_chunks``, which streams
chunk by chunk), raw brdf evaluations per second measured in the same run on
the same chunk shape (the simulator's overhead is their ratio), and the peak
resident memory next to the chunk and full-capture sizes.

    python scripts/bench_stage.py                      # 512^2 texels, 346 lights
    python scripts/bench_stage.py --resolution 256     # quicker
"""

from __future__ import annotations

import argparse
import resource
import time

import jax
import jax.numpy as jnp
import numpy as np
from _common import head_scene, uniform_lambert_ggx

import stage


def stage_backend() -> str:
    import trimesh

    return "embree" if trimesh.ray.has_embree else "pure-numpy ray casting"


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def bench_brdf(n: int, repeats: int) -> float:
    """Raw lambert_ggx evaluations per second on n (wi, wo) pairs, jitted."""
    rng = np.random.default_rng(0)

    def hemisphere(n):
        w = rng.normal(size=(n, 3))
        w[:, 2] = np.abs(w[:, 2])
        return jnp.asarray(w / np.linalg.norm(w, axis=1, keepdims=True), jnp.float32)

    wi, wo = hemisphere(n), hemisphere(n)
    mat = uniform_lambert_ggx(n)
    f = jax.jit(lambda m, a, b: m(a, b))
    f(mat, wi, wo).block_until_ready()
    t = time.perf_counter()
    for _ in range(repeats):
        f(mat, wi, wo).block_until_ready()
    return n * repeats / (time.perf_counter() - t)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--resolution", type=int, default=512, help="texel grid side (default 512)")
    ap.add_argument("--light-chunk", type=int, default=64)
    ap.add_argument("--sample-chunk", type=int, default=1 << 15)
    ap.add_argument("--max-chunks", type=int, default=0, help="stop shading after this many chunks (0: all)")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    mesh, surf, rig, cam = head_scene(args.resolution)
    P, L = surf.num_samples, rig.num_lights
    print(f"devices: {jax.devices()}  samples: {P}  lights: {L}  geometry: {time.perf_counter() - t0:.1f} s")

    t0 = time.perf_counter()
    lv = stage.light_visibility(mesh, surf, rig, packed=True, chunk=1 << 20)
    cv = stage.camera_visibility(mesh, surf, [cam])
    t_vis = time.perf_counter() - t0
    print(f"visibility (one-off, {stage_backend()}): {t_vis:.1f} s, {P * L / t_vis / 1e6:.2f} M sample-lights/s; "
          f"packed light mask {lv.nbytes / 2**20:.1f} MiB (bool would be {P * L / 2**20:.1f} MiB); "
          f"peak RSS so far {_rss_mb():.0f} MiB", flush=True)

    mat = uniform_lambert_ggx(P)
    # Warm-up: compile the chunk shapes once.
    for _, _, _, rad, _ in stage.simulate_chunks(surf, rig, [cam], mat, lv, cv, light_chunk=args.light_chunk,
                                                 sample_chunk=args.sample_chunk):
        rad.block_until_ready()
        break
    rss_before = _rss_mb()
    done, n_chunks, total = 0, 0, 0.0
    t0 = time.perf_counter()
    for _, ls, ps, rad, _ in stage.simulate_chunks(surf, rig, [cam], mat, lv, cv, light_chunk=args.light_chunk,
                                                   sample_chunk=args.sample_chunk):
        total += float(jnp.sum(rad))  # consume the chunk (a writer would store it here)
        done += (ls.stop - ls.start) * (ps.stop - ps.start)
        n_chunks += 1
        if args.max_chunks and n_chunks >= args.max_chunks:
            break
    t_shade = time.perf_counter() - t0
    rate = done / t_shade
    print(f"shading: {done} sample-lights in {t_shade:.1f} s = {rate / 1e6:.2f} M sample-lights/s "
          f"(checksum {total:.4g})", flush=True)
    raw = bench_brdf(args.light_chunk * args.sample_chunk, repeats=3)
    chunk_mb = args.light_chunk * args.sample_chunk * 3 * 4 / 2**20
    capture_mb = P * L * 3 * 4 / 2**20
    print(f"raw brdf.lambert_ggx: {raw / 1e6:.2f} M evaluations/s on {args.light_chunk * args.sample_chunk} pairs; "
          f"simulator / raw = {rate / raw:.2f}")
    print(f"memory: peak RSS {_rss_mb():.0f} MiB (before shading {rss_before:.0f} MiB); one radiance chunk "
          f"{chunk_mb:.0f} MiB; the full capture would be {capture_mb:.0f} MiB (float32)")


if __name__ == "__main__":
    main()
