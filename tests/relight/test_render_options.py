"""Typed render methods (relight.render.Rig, Dense, Lights, Fast, Reference): the same
renders as the string spellings, their defaults are DEFAULTS, and bad
settings are refused when the object is built."""

import jax
import numpy as np
import pytest

import relight
import stage
from relight import render
from tests.helpers import REFUSED
from tests.scenes import small_render_scene


@pytest.fixture(scope="module")
def small():
    return small_render_scene(2)


def test_objects_render_what_the_strings_render(small):
    mesh, surf, maps, env, wo = small
    dome = stage.geodesic_dome(1, radius_mm=400.0, near_field=True)
    pairs = [
        (render.Dense(rows=8), dict(method="dense", resolution=8)),
        (render.Rig(rig=dome, supersample=2), dict(method="rig", rig=dome, supersample=2)),
        (render.Lights(lights=32), dict(method="lights", lights=32)),
    ]
    for obj, kw in pairs:
        a = render.render_samples(maps, surf, env, wo, method=obj, mesh=mesh, key=jax.random.PRNGKey(4))
        b = render.render_samples(maps, surf, env, wo, mesh=mesh, key=jax.random.PRNGKey(4), **kw)
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=obj.name)
        assert np.asarray(a).max() > 0
    # The Monte Carlo and fast methods resolve to the same settings either way (not rendered here: their
    # kernels are compiled by tests/relight/test_render.py).
    from relight.render._methods import _settings

    for obj, kw in [(render.Reference(samples=16, heuristic="balance"), dict(samples=16, heuristic="balance")),
                    (render.Fast(ao_rays=8, levels=3), dict(ao_rays=8, levels=3))]:
        a, b = _settings(obj, {"chunk": 64}), _settings(obj.name, {"chunk": 64, **kw})
        assert a == b and a["method"] == obj


def test_defaults_are_the_objects_defaults():
    assert render.DEFAULTS == {"rig": render.Rig().settings(), "dense": render.Dense().settings(),
                               "fast": render.Fast().settings(), "reference": render.Reference().settings(),
                               "lights": render.Lights().settings()}
    assert render.DEFAULTS["dense"] == {"resolution": 32}
    assert render.Reference().samples == 256 and render.Rig().weights == "voronoi"
    assert tuple(render.METHODS) == ("rig", "dense", "fast", "reference", "lights")
    assert render.DEFAULTS["lights"] == {"lights": 256}


def test_bad_method_objects(small):
    mesh, surf, maps, env, wo = small
    for build, msg in [
        (lambda: render.Dense(rows=1), "rows"),
        (lambda: render.Fast(ao_rays=0), "ao_rays"),
        (lambda: render.Reference(samples=1), "samples"),
        (lambda: render.Reference(env_fraction=1.5), "env_fraction"),
        (lambda: render.Reference(heuristic="max"), "heuristic"),
        (lambda: render.Rig(weights="nearest"), "weights"),
        (lambda: render.Rig(supersample=0), "supersample"),
    ]:
        with pytest.raises(ValueError, match=msg):
            build()
    with pytest.raises(ValueError, match="given as an object"):
        render.render_samples(maps, surf, env, wo, method=render.Dense(rows=8), resolution=16)
    with pytest.raises(ValueError, match="rig="):
        render.render_samples(maps, surf, env, wo, method=render.Rig(), rig=stage.geodesic_dome(1))
    with pytest.raises(ValueError, match="no setting"):
        render.render_samples(maps, surf, env, wo, method=render.Dense(rows=8), samples=4)
    # REFUSED: our ValueError, or (tests only) the annotation checker's TypeCheckError naming the parameter.
    with pytest.raises(REFUSED, match="unknown relighting method|parameter 'method'"):
        render.render_samples(maps, surf, env, wo, method=object())
    with pytest.raises(ValueError, match="unknown relighting method"):
        render.render_samples(maps, surf, env, wo, method="raytrace")


def test_terminator_setting(small):
    """On a convex coarse sphere nothing but the horizon blocks light: with the
    shadow-terminator origins (default) every method that casts rays renders
    what it renders without a mesh (no shadows); ``terminator=False`` (rays
    from the flat facets, as Mitsuba casts them) darkens the facets turned away
    from the light on the terminator side. A non-bool is refused."""
    mesh, _, _, env, _ = small
    surf = stage.texel_samples(mesh, 32)
    maps = relight.material_maps(surf, 0.5, 0.04, 0.3)
    wo = np.asarray(surf.normal)
    for method in (render.Dense(rows=8), render.Lights(lights=32)):
        free = np.asarray(render.render_samples(maps, surf, env, wo, method=method))
        smooth = np.asarray(render.render_samples(maps, surf, env, wo, method=method, mesh=mesh))
        flat = np.asarray(render.render_samples(maps, surf, env, wo, method=method, mesh=mesh, terminator=False))
        # float32 kernels: 1e-5 of the brightest sample.
        np.testing.assert_allclose(smooth, free, rtol=0, atol=1e-5 * free.max())
        assert np.all(flat <= smooth + 1e-6 * free.max())
        assert (smooth - flat).max() > 1e-3 * free.max()
    with pytest.raises(ValueError, match="terminator"):
        render.render_samples(maps, surf, env, wo, method="dense", mesh=mesh, terminator=1)
