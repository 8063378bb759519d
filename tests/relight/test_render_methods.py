"""Render methods own their behaviour: each Module prepares and shades itself (``prepare``, ``geometry``,
``shade``) and that is exactly what ``render_samples`` does with it; strings are spellings turned into
Modules by ``method_from_name``; no method-name dispatch inside ``relight.render``; the turntable's
rotations and a camera's rescaling have one home."""

import ast
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import stage
from relight import render
from relight.envmap import rotation_matrix
from tests.scenes import small_render_scene

RENDER = Path(render.__file__).parent


@pytest.fixture(scope="module")
def small():
    return small_render_scene(3)


def test_prepare_geometry_shade_is_render_samples(small):
    """The three steps of a method, called by hand, give render_samples' radiance bit for bit (directional
    methods; the same loop serves Fast and Reference)."""
    mesh, surf, maps, env, wo = small
    for m in (render.Dense(rows=4), render.Lights(lights=16)):
        lighting = m.prepare(env)
        geometry = m.geometry(lighting, maps, surf, mesh)
        out, M = m.shade(lighting, geometry, maps, surf, jnp.asarray(wo, jnp.float32))
        ref = render.render_samples(maps, surf, env, wo, method=m, mesh=mesh)
        np.testing.assert_array_equal(np.asarray(out), np.asarray(ref), err_msg=m.name)
        assert M is None  # no subsurface sample
        assert isinstance(lighting, (render.DenseLighting, render.LightsLighting))
        assert isinstance(geometry, render.DirectionalGeometry)


def test_method_from_name():
    assert render.method_from_name("dense", resolution=8) == render.Dense(rows=8)
    assert render.method_from_name("reference", samples=16) == render.Reference(samples=16)
    assert render.method_from_name("rig") == render.Rig()
    assert {render.method_from_name(n).name for n in render.METHODS} == set(render.METHODS)
    with pytest.raises(ValueError, match="unknown relighting method"):
        render.method_from_name("raytrace")
    with pytest.raises(ValueError, match="no setting"):
        render.method_from_name("dense", samples=4)
    with pytest.raises(ValueError, match="rows"):
        render.method_from_name("dense", resolution=1)


def test_no_method_name_dispatch_in_render():
    """No comparison of a value with a method's string name inside relight.render (strings are spellings)."""
    names = set(render.METHODS)
    for path in sorted(RENDER.glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Compare):
                consts = [c for c in [node.left, *node.comparators] if isinstance(c, ast.Constant)]
                for c in consts:
                    assert c.value not in names, f"{path.name}:{node.lineno}: compares with method name {c.value!r}"
                for c in node.comparators:
                    if isinstance(c, (ast.Tuple, ast.List, ast.Set)):
                        vals = {e.value for e in c.elts if isinstance(e, ast.Constant)}
                        assert not vals & names, f"{path.name}:{node.lineno}: tests membership in method names"


def test_modules_are_short():
    for folder in (RENDER, RENDER.parent / "view"):
        for path in folder.glob("*.py"):
            assert len(path.read_text().splitlines()) <= 600, path


def test_y_rotations_and_scaled_camera(small):
    mesh = small[0]
    rots = render.y_rotations([0.0, 90.0, 225.0])
    assert rots.shape == (3, 3, 3) and rots.dtype == np.float64
    np.testing.assert_allclose(rots[0], np.eye(3), atol=1e-12)
    for a, r in zip([0.0, 90.0, 225.0], rots, strict=True):
        ref = np.asarray(rotation_matrix(np.array([0.0, 1.0, 0.0]), np.deg2rad(a)), np.float64)
        np.testing.assert_allclose(r, ref, atol=1e-6)
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-6)
    cam = stage.front_camera(mesh, 64)
    half = render.scaled_camera(cam, 32)
    assert (half.width, half.height) == (32, 32)
    assert render.scaled_camera(cam, 64) is cam
    # The same scene point lands on the same relative pixel position.
    p = jnp.asarray([[0.0, 10.0, 20.0]], jnp.float32)
    np.testing.assert_allclose(np.asarray(half.project(p)[0]) / 32, np.asarray(cam.project(p)[0]) / 64, atol=1e-5)
    with pytest.raises(ValueError, match="size"):
        render.scaled_camera(cam, 0)


def test_input_kind_names_the_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such input folder"):
        render.input_kind(tmp_path / "missing")
    with pytest.raises(ValueError, match="neither a capture folder"):
        render.input_kind(tmp_path)

