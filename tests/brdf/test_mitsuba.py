"""Agreement with Mitsuba 3 on a few hundred pairs (Mitsuba is in the test extras;
its ``scalar_rgb`` variant needs no LLVM or GPU). The full cross-check is
``python scripts/check_mitsuba.py``."""

import importlib.util
import sys
from pathlib import Path

import mitsuba  # noqa: F401  (a test dependency: a missing install fails here instead of skipping)

_SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "check_mitsuba.py"


def test_agrees_with_mitsuba():
    spec = importlib.util.spec_from_file_location("check_mitsuba", _SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # the script defines an equinox Module (a dataclass)
    spec.loader.exec_module(mod)
    only = ("ggx conductor ax=0.3 ay=0.1", "lambert", "burley diffuse roughness=1.0")
    results = mod.cross_check(n_pairs=200, seed=1, only=only)
    assert len(results) == 3
    for r in results:
        assert r["ok"], r  # 1e-4 relative, float64 ours vs float32 Mitsuba
