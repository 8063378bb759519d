"""The Ceres baseline of ``scripts/bench_fit.py``: compile ``scripts/ceres_fit.cc``, hand it the texels'
observations and starts, run it, read its solutions back.

Ceres (http://ceres-solver.org) is what a performance-minded C++ user would fit these per-texel problems with;
the benchmark compiles the solver itself (g++ -O3 -march=native) once per run, so the line measures this machine.
It needs Debian's ``libceres-dev`` (Ceres 2.1, with Eigen 3 and glog); without it :func:`build` says how to
install it and the benchmark prints its other lines. Nothing here is library logic.

Data exchange, in a temporary folder: raw little-endian files (``ceres_fit.cc`` lists them), float64, only each
texel's valid observations (the mask applied, as the scipy loop does), texels one after another with an offset
table. The timings: ``solve_s`` is the C++ solve alone (std::chrono around the threads), ``wall_s`` adds writing
the inputs here, starting the process, its reading and writing, and reading the outputs here.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

SOURCE = Path(__file__).resolve().parent / "ceres_fit.cc"
# Ceres's Summary times per texel (stats.f64's columns 4-7), summed over texels (thread-seconds).
PHASES = ("solve", "jacobian", "residual", "linear")
INSTALL = "apt-get install -y libceres-dev  (Debian / Ubuntu: Ceres 2.1 with Eigen 3 and glog)"


def _flags() -> list[str] | None:
    """Compiler and linker flags for Ceres: its pkg-config file where there is one (Debian ships none), else
    Eigen's and glog's pkg-config files or Debian's paths; None when Ceres's headers are not found."""

    def pkg(*names):
        run = subprocess.run(["pkg-config", "--cflags", "--libs", *names], capture_output=True, text=True,
                             check=False) if shutil.which("pkg-config") else None
        return run.stdout.split() if run is not None and run.returncode == 0 else None

    found = pkg("ceres")
    if found is not None:
        return found
    if not Path("/usr/include/ceres/ceres.h").is_file():
        return None
    eigen = pkg("eigen3") or ["-I/usr/include/eigen3"]
    glog = pkg("libglog") or ["-lglog"]
    return [*eigen, "-lceres", *glog]


def build(folder: Path) -> tuple[Path | None, float, str]:
    """Compile ``ceres_fit.cc`` into ``folder``: (binary or None, compile seconds, why not where None)."""
    cxx = shutil.which(os.environ.get("CXX", "g++"))
    flags = _flags()
    if cxx is None or flags is None:
        missing = "a C++ compiler (g++)" if cxx is None else "Ceres's headers (ceres/ceres.h)"
        return None, 0.0, f"{missing} not found; to add the Ceres line: {INSTALL}"
    exe = Path(folder) / "ceres_fit"
    t0 = time.perf_counter()
    run = subprocess.run([cxx, "-O3", "-march=native", "-std=c++17", "-DNDEBUG", str(SOURCE), "-o", str(exe),
                          *flags, "-lpthread"], capture_output=True, text=True, check=False)
    if run.returncode:
        return None, 0.0, f"compiling {SOURCE.name} failed ({INSTALL}?):\n{run.stderr[-2000:]}"
    return exe, time.perf_counter() - t0, ""


def write_inputs(folder: Path, obs, w, wi, wo, irr, u0, cauchy: float = 0.1):
    """Write the texels' valid observations (weight > 0), starts and Cauchy scales (``cauchy`` x the texel's
    RMS radiance + 1e-12, as bench_fit's scipy loop) as ``ceres_fit.cc`` reads them. The arrays are [n, N, 3]
    (u0 [n, 7]) of the texels to fit. Returns the per-texel valid mask [n, N]."""
    import numpy as np

    folder = Path(folder)
    valid = np.asarray(w)[:, :, 0] > 0
    count = valid.sum(1)
    rows = {name: np.ascontiguousarray(np.asarray(x, np.float64)[valid]) for name, x in
            (("obs", obs), ("wi", wi), ("wo", wo), ("irr", irr))}
    o = np.asarray(obs, np.float64)
    scale = np.sqrt(np.sum(np.where(valid[..., None], o * o, 0.0), axis=(1, 2)) / np.maximum(3 * count, 1))
    np.concatenate([[0], np.cumsum(count)]).astype("<i8").tofile(folder / "offsets.i64")
    for name, x in rows.items():
        x.astype("<f8").tofile(folder / f"{name}.f64")
    np.ascontiguousarray(u0, "<f8").tofile(folder / "start.f64")
    (cauchy * scale + 1e-12).astype("<f8").tofile(folder / "scale.f64")
    return valid


def solve(exe: Path, arrays, floor: float, *, repeat: int = 3, threads: int | None = None, loss: str = "sqrt",
          linear: str = "qr", jacobian: str = "autodiff", max_iterations: int = 60) -> dict:
    """Run the Ceres solver ``repeat`` times on ``arrays`` = (obs, w, wi, wo, irr, u0) of the texels to fit.

    Returns dict(u [n, 7], cost0 / cost [n] (Ceres's 0.5 sum r^2 at the start and at the solution),
    iterations [n], converged [n] bool, solve_s (fastest C++ solve), cpu_s (least process CPU seconds of a
    solve, all threads), phases (that solve's seconds summed over
    texels and threads, as Ceres's Summary times them: ``PHASES``), wall_s (fastest call including the file
    exchange and the process start), threads, version)."""
    import numpy as np

    n = len(arrays[-1])
    best = dict(solve_s=np.inf, wall_s=np.inf, cpu_s=np.inf)
    with tempfile.TemporaryDirectory(prefix="ceres_fit_") as tmp:
        for _ in range(repeat):
            t0 = time.perf_counter()
            write_inputs(Path(tmp), *arrays)
            cmd = [str(exe), tmp, repr(float(floor)), "--loss", loss, "--linear", linear, "--jacobian", jacobian,
                   "--max-iterations", str(max_iterations), "--threads", str(threads or os.cpu_count() or 1)]
            run = subprocess.run(cmd, capture_output=True, text=True, check=False)
            if run.returncode:
                raise SystemExit(f"ceres_fit failed ({' '.join(cmd)}):\n{run.stderr[-2000:]}")
            info = json.loads(run.stdout.strip().splitlines()[-1])
            u = np.fromfile(Path(tmp) / "solution.f64", "<f8").reshape(n, -1)
            stats = np.fromfile(Path(tmp) / "stats.f64", "<f8").reshape(n, 8)
            wall = time.perf_counter() - t0
            if info["solve_s"] < best["solve_s"]:
                best.update(solve_s=info["solve_s"], phases=dict(zip(PHASES, stats[:, 4:].sum(0), strict=True)))
            best["wall_s"] = min(best["wall_s"], wall)
            best["cpu_s"] = min(best["cpu_s"], info["cpu_s"])
    return dict(best, u=u, cost0=stats[:, 0], cost=stats[:, 1], iterations=stats[:, 2], converged=stats[:, 3] > 0,
                threads=info["threads"], version=info["ceres"])
