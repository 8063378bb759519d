"""Agreement with Mitsuba 3 on a few hundred pairs (Mitsuba is in the test extras;
its ``scalar_rgb`` variant needs no LLVM or GPU). The full cross-check is
``python scripts/check_mitsuba.py``."""

import mitsuba  # noqa: F401  (a test dependency: a missing install fails here instead of skipping)

from ..helpers import load_script


def test_agrees_with_mitsuba():
    mod = load_script("check_mitsuba")
    only = ("ggx conductor ax=0.3 ay=0.1", "lambert", "burley diffuse roughness=1.0")
    results = mod.cross_check(n_pairs=200, seed=1, only=only)
    assert len(results) == 3
    for r in results:
        assert r["ok"], r  # 1e-4 relative, float64 ours vs float32 Mitsuba
