"""scripts/eval_mitsuba_outside.py's second material, small: the head rendered by Mitsuba with the ladder's
material and with ``roughplastic`` (a material no rung holds), from the same albedo texture."""

import json

import numpy as np
import pytest

from ..helpers import load_script

# 48 px images, 1 camera, 4 lights, 4 spp, 16 x 16 texels: two renders of a few seconds.
SMALL = dict(size=48, lights=4, cameras=1, spp=4, resolution=16)


def test_roughplastic_takes_the_albedo_texture_at_its_scale(tmp_path):
    """Mitsuba's roughplastic (``nonlinear`` false) scatters rho t_i t_o / (pi eta^2 (1 - F_int)) diffusely, with
    t the rough interface's transmittance and F_int its internal diffuse reflectance: its own BSDF evaluation
    (scalar_rgb, rho 0.5, alpha 0.35, eta 1.5) is 0.70x the Lambertian rho / pi at (theta_i, theta_o) = (0, 40)
    degrees, 0.64x at (45, 45) and 0.52x at (70, 70). The median ratio of the two captures' pixels (the ladder's
    also holds its GGX lobe) is therefore between 0.5 and 0.8; an albedo texture read at the wrong scale
    (write_mitsuba_scene's diffuse_blend.exr is rho / 0.01; its diffuse_x2.exr 2 rho) is off by 100x or 2x.
    The render cache is reused while its settings hold, and redone when they change."""
    pytest.importorskip("mitsuba", reason="Mitsuba 3 renders the capture (a test extra: pip install -e '.[test]')")
    from relight.io import read_png

    script = load_script("eval_mitsuba_outside")
    folders = {m: script.render(tmp_path, m, progress=lambda *_: None, **SMALL) for m in script.MATERIALS}
    scene = (tmp_path / "roughplastic" / "scene_cam000" / "olat.xml").read_text()
    assert 'type="roughplastic"' in scene and "mitsuba/albedo.exr" in scene
    mask = read_png(folders["ladder"] / "cam000" / "mask.png").reshape(SMALL["size"], SMALL["size"]) > 0
    ratios = []
    for light in range(SMALL["lights"]):
        a, b = (read_png(folders[m] / "cam000" / f"l{light:03d}.png").astype(np.float64) for m in script.MATERIALS)
        lit = mask[..., None] & (a > 0.02 * 65535) & (b > 0)
        ratios.append(b[lit] / a[lit])
    median = float(np.median(np.concatenate(ratios)))
    assert 0.5 < median < 0.8, median
    # The cache: the same settings reuse the render (no new file), other settings render again.
    stamp = tmp_path / "ladder" / "settings.json"
    before = stamp.stat().st_mtime_ns
    assert script.render(tmp_path, "ladder", progress=lambda *_: None, **SMALL) == folders["ladder"]
    assert stamp.stat().st_mtime_ns == before
    script.render(tmp_path, "ladder", progress=lambda *_: None, **(SMALL | {"spp": 2}))
    assert json.loads(stamp.read_text())["spp"] == 2
