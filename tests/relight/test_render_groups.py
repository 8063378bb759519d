"""A camera-view render in bands of rows shades each band's pixel samples in groups of one sample count, so
JAX compiles (and keeps) one program per operation for the whole image instead of one per band's hit count
(tests/relight/test_bands.py: the banded pixels are the whole image's). A view whose rays all miss is the
background."""

from __future__ import annotations

import numpy as np

import stage
from tests.scenes import small_render_scene


def _camera(width=16, height=12, target=(0.0, 0.0, 0.0)):
    return stage.camera_ring(1, 600.0, target=target, fov_deg=14.0, width=width, height=height)[0]


def test_bands_shade_groups_of_one_sample_count(monkeypatch):
    import relight.image._preview as preview
    from relight.render import Dense, render_view
    from relight.render._abstract import AbstractMethod

    mesh, surf, maps, env, _ = small_render_scene(5)
    counts = []
    shade = AbstractMethod.shade

    def counting(self, lighting, geometry, maps, surface, wo, **kw):
        counts.append(surface.num_samples)
        return shade(self, lighting, geometry, maps, surface, wo, **kw)

    monkeypatch.setattr(AbstractMethod, "shade", counting)
    monkeypatch.setattr(preview, "BAND_RAYS", 3 * 16)  # 4 bands of 3 rows, groups of 6 samples
    img = render_view(maps, surf, mesh, _camera(), env, method=Dense(rows=4), supersample=1, background=False)
    # The sphere covers part of every band: several groups, all of one count.
    assert len(counts) > 4, counts
    assert set(counts) == {3 * 16 // 8}, counts
    assert np.all(np.isfinite(img)) and float(np.max(img)) > 0


def test_a_view_without_hits_is_the_background():
    from relight.render import Dense, environment_behind, render_view

    mesh, surf, maps, env, _ = small_render_scene(6)
    cam = _camera(8, 6, target=(5000.0, 0.0, 0.0))  # looking away from the sphere: every ray misses
    assert not stage.primary_hits(mesh, cam, 1)[0].any()
    img = render_view(maps, surf, mesh, cam, env, method=Dense(rows=4), supersample=1)
    np.testing.assert_allclose(img, environment_behind(env, mesh, cam, supersample=1), rtol=1e-6)
    assert float(np.min(img)) > 0
    assert np.all(render_view(maps, surf, mesh, cam, env, method=Dense(rows=4), supersample=1, background=False) == 0)
