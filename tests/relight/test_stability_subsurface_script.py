"""scripts/stability_subsurface.py's core (``sweep``) on a two-cell grid of a small strip: the
record structure, an identifiable cell (mfp 2 mm on 0.25 mm texels, no noise; those texels share
the simulation's grid, so the fit's own discretisation is exact there) judged "ok", and an
unidentifiable one (mfp 0.05 mm on 1.25 mm texels: 90% of the red profile's energy lies within
0.04 mm, ~1/30 of a texel) not "ok". The full sweep is ``python scripts/stability_subsurface.py``."""

import numpy as np
import pytest

from ..helpers import load_script


@pytest.fixture(scope="module")
def script():
    return load_script("stability_subsurface")


def test_identifiable_cell_is_ok_and_subtexel_mfp_is_not(script):
    # A 7.5 x 1.25 mm strip between 2 mm walls: 150 texels at 0.25 mm, 6 at 1.25 mm (odd multiples).
    scene = script.Scene(0.25, strip_mm=(7.5, 1.25), wall_mm=2.0)
    fine = script.Cell(texel=0.25, noise=0.0, lights=85)
    coarse = script.Cell(texel=1.25, noise=0.0, lights=85)
    good = script.sweep([2.0], [fine], scene=scene)
    bad = script.sweep([0.05], [coarse], scene=scene)
    assert len(good) == 1 and len(bad) == 1
    for r, P in ((good[0], 150), (bad[0], 6)):
        assert {"mfp", "texel", "noise", "lights", "brdf", "footprint", "err", "flagged", "verdict",
                "median_mfp", "seconds"} <= set(r)
        assert r["texels"] == P and r["err"].shape == (3,) and 0.0 <= r["flagged"] <= 1.0
        assert r["verdict"] in ("ok", "biased", "failed")
    g, b = good[0], bad[0]
    assert g["verdict"] == "ok", g
    # ok means: every channel's median relative error within the script's 15% bar, at most half flagged.
    assert np.all(g["err"] <= script.ERR_OK) and g["flagged"] <= script.FLAGGED_FAILED
    np.testing.assert_allclose(g["median_mfp"], 2.0, rtol=script.ERR_OK)
    assert b["verdict"] != "ok", b


def test_verdict_thresholds(script):
    assert script.verdict(np.array([0.1, 0.05, 0.14]), 0.0) == "ok"
    assert script.verdict(np.array([0.1, 0.3, 0.14]), 0.2) == "biased"
    assert script.verdict(np.array([0.1, 0.6, 0.14]), 0.2) == "failed"
    assert script.verdict(np.array([0.01, 0.01, 0.01]), 0.6) == "failed"  # most texels flagged
    assert script.verdict(np.array([np.nan, 0.01, 0.01]), 0.0) == "failed"  # a channel with no fitted texel
