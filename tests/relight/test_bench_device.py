"""scripts/bench_device.py: ``--quick`` in a fresh CPU process writes one table row per kernel with positive,
finite throughputs and a fraction of the (measured) peak in (0, 1]: above 1, XLA's cost count or the peak would
be wrong. And the datasheet table matches the names JAX gives the GPUs it lists, and no other. The full run is
``python scripts/bench_device.py`` (docs/scaling.md, "On a GPU: the prepared benchmark")."""

import math
import os
import subprocess
import sys
from types import SimpleNamespace

import pytest

from ..helpers import SCRIPTS, load_script, xla_flags

KERNELS = ["fit", "simulate", "relight", "brdf"]


@pytest.fixture(scope="module")
def script():
    return load_script("bench_device")


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _main_table(text: str) -> list[dict[str, str]]:
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| kernel | size | backend device |"))
    head = _cells(lines[start])
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(head, _cells(line), strict=True)))
    return rows


def test_quick_run_on_the_cpu_writes_one_row_per_kernel(tmp_path):
    out = tmp_path / "device.md"
    env = os.environ | {"XLA_FLAGS": xla_flags(), "JAX_PLATFORMS": "cpu"}
    run = subprocess.run([sys.executable, str(SCRIPTS / "bench_device.py"), "--quick", "--out", str(out)],
                         capture_output=True, text=True, env=env, cwd=SCRIPTS.parent, timeout=600, check=False)
    assert run.returncode == 0, run.stderr[-3000:]
    text = out.read_text()
    assert not list(tmp_path.glob("*.tmp")), "the table is written through a temporary file, then renamed"
    rows = _main_table(text)
    assert [r["kernel"] for r in rows] == KERNELS
    for r in rows:
        rate = float(r["throughput"].split()[0])
        assert math.isfinite(rate) and rate > 0, r
        # A CPU-only machine: the CPU column is the device's own run.
        assert r["CPU throughput"] == r["throughput"] + " (same run)" and float(r["ratio"]) == 1.0, r
        for col in ("compile s", "wall s", "achieved GFLOP/s", "achieved GB/s"):
            assert math.isfinite(float(r[col])) and float(r[col]) >= 0, (col, r)
        assert float(r["wall s"]) > 0 and float(r["achieved GFLOP/s"]) > 0 and float(r["achieved GB/s"]) > 0, r
        assert 0 < float(r["fraction of peak"]) <= 1, r
        assert r["which peak"].startswith(("FP32 ", "memory ")), r
    assert "measured before and after the kernels" in text  # a CPU has no datasheet entry
    for name in KERNELS:
        assert f"{name} on cpu:0: " in run.stderr  # progress per kernel


@pytest.mark.parametrize("kind, name", [
    ("NVIDIA H100 80GB HBM3", "NVIDIA H100 SXM"),
    ("NVIDIA H100 PCIe", "NVIDIA H100 PCIe"),
    ("NVIDIA H100 NVL", "NVIDIA H100 NVL"),
    ("NVIDIA H200", "NVIDIA H200 SXM"),
    ("NVIDIA A100-SXM4-80GB", "NVIDIA A100 80GB SXM"),
    ("NVIDIA A100 80GB PCIe", "NVIDIA A100 80GB PCIe"),
    ("NVIDIA A100-PCIE-40GB", "NVIDIA A100 40GB"),
    ("NVIDIA L40S", "NVIDIA L40S"),
    ("NVIDIA L4", "NVIDIA L4"),
    ("Tesla T4", "NVIDIA T4"),
    ("NVIDIA GH200 480GB", None),  # Grace Hopper: another memory system, not an H200
    ("NVIDIA H100 80GB HBM3 MIG 1g.10gb", None),  # a slice of the chip
    ("NVIDIA A10G", None),
])
def test_datasheet_matches_the_named_gpus_only(script, kind, name):
    peak = script.datasheet_peak(SimpleNamespace(device_kind=kind, platform="gpu"))
    assert (None if peak is None else peak.source) == (None if name is None else f"datasheet: {name}")
    assert script.datasheet_peak(SimpleNamespace(device_kind="cpu", platform="cpu")) is None


def test_fraction_is_that_of_the_binding_resource(script):
    peak = script.Peak(flops=100e9, bandwidth=10e9, source="test")
    compute = script.Run("k", "s", "d", 0.0, 2.0, 1.0, flops=100e9, nbytes=4e9)  # 0.5 of FLOP/s, 0.2 of memory
    memory = script.Run("k", "s", "d", 0.0, 2.0, 1.0, flops=20e9, nbytes=16e9)  # 0.1 of FLOP/s, 0.8 of memory
    assert compute.fraction(peak) == (pytest.approx(0.5), "FP32 100 GFLOP/s")
    assert memory.fraction(peak) == (pytest.approx(0.8), "memory 10 GB/s")
