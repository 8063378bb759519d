"""MaterialMaps refuse values outside their documented ranges, naming the map
and the number of bad samples (material_maps, the MaterialMaps constructor,
and a texture set's .maps), accept the bounds themselves, make nonzero normals
unit, and leave traced maps (under jit / grad) to run."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import relight
import stage
from relight.io import texture_set
from relight.materials import ALPHA_MAX, MODELS

from ..scenes import uv_sphere


@pytest.fixture(scope="module")
def surf():
    return stage.texel_samples(uv_sphere(radius=50.0, n_lat=8, n_lon=16), 16)


def _good(P):
    return dict(rho_d=np.full((P, 3), 0.5), rho_s=np.full((P, 1), 0.04), alpha=np.full((P, 1), 0.3))


def _bad_rows(P):
    return np.array([1, 4, 9]) % P


# (keyword, bad value at three samples, what the message must name)
CASES = [
    ("rho_s", 5.0, r"rho_s \(specular albedo, Schlick F0\) must be in \[0, 1\]"),
    ("rho_s", -0.01, r"rho_s .* must be in \[0, 1\]"),
    ("rho_d", 1.2, r"rho_d \(diffuse albedo\) must be in \[0, 1\]"),
    ("rho_d", -0.5, r"rho_d .* must be in \[0, 1\]"),
    ("alpha", 1e30, r"alpha \(GGX roughness\) must be in \(0, 1\]"),
    ("alpha", 0.0, r"alpha .* must be in \(0, 1\]"),
    ("model", 2.5, r"model must be an integer rung of the ladder 0\.\.4"),
    ("model", 7, r"model must be an integer rung"),
    ("model", -1, r"model must be an integer rung"),
    ("normal", 0.0, r"normal must be nonzero"),
    ("tangent", "parallel", r"tangent must be nonzero and not parallel to the normal"),
    ("mfp", -1.0, r"mfp \(mean free path\) must be >= 0"),
    ("rho_d", np.nan, r"material_maps: rho_d has NaN or Inf"),
]


def _maps_kwargs(surf, key, value):
    P = surf.num_samples
    kw = _good(P)
    kw["normal"] = np.asarray(surf.normal, np.float64).copy()
    kw["tangent"] = np.asarray(surf.tangent, np.float64).copy()
    kw["model"] = np.full(P, relight.materials.GGX, np.float64)
    kw["mfp"] = np.zeros((P, 3))
    rows = _bad_rows(P)
    if key == "tangent":
        kw["tangent"][rows] = 2.0 * kw["normal"][rows]
    else:
        kw[key] = np.asarray(kw[key], np.float64)
        kw[key][rows] = value
    return kw


@pytest.mark.parametrize("key, value, match", CASES)
def test_material_maps_refuses_out_of_range_values(surf, key, value, match):
    kw = _maps_kwargs(surf, key, value)
    with pytest.raises(ValueError, match=match) as err:
        relight.material_maps(surf, kw.pop("rho_d"), **kw)
    if "NaN" not in match:
        assert f"3 of {surf.num_samples} sample(s)" in str(err.value)  # the count of bad samples
        assert "first: [1, 4, 9]" in str(err.value)


# The constructor's model map is an int array (its annotation): 2.5 cannot reach it; NaN is named as not finite.
CONSTRUCTOR_CASES = [c for c in CASES[:-1] if not (c[0] == "model" and c[1] == 2.5)] + [
    ("rho_d", np.nan, r"MaterialMaps: rho_d \(diffuse albedo\) must be finite")]


@pytest.mark.parametrize("key, value, match", CONSTRUCTOR_CASES)
def test_the_constructor_refuses_them_too(surf, key, value, match):
    """MaterialMaps(...) built directly (a hand-made set, render's lookups) is
    held to the same ranges."""
    kw = _maps_kwargs(surf, key, value)
    alpha = np.repeat(kw["alpha"], 2, axis=1)
    f = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731
    with pytest.raises(ValueError, match=match) as err:
        relight.MaterialMaps(f(kw["rho_d"]), f(kw["rho_s"]), f(alpha), f(kw["normal"]), f(kw["tangent"]),
                             f(kw["mfp"]), jnp.asarray(kw["model"], jnp.int32))
    assert str(err.value).startswith("MaterialMaps: ") and f"3 of {surf.num_samples} sample(s)" in str(err.value)


def test_bounds_are_accepted_and_normals_made_unit(surf):
    P = surf.num_samples
    n = np.asarray(surf.normal, np.float64)
    scale = np.linspace(0.5, 3.0, P)[:, None]
    maps = relight.material_maps(surf, np.ones((P, 3)), np.zeros((P, 1)), np.full((P, 1), ALPHA_MAX),
                                 normal=n * scale, tangent=np.asarray(surf.tangent) + 0.3 * n,
                                 model=np.full(P, float(len(MODELS) - 1)))
    got_n = np.asarray(maps.normal, np.float64)
    np.testing.assert_allclose(np.linalg.norm(got_n, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(got_n, n / np.linalg.norm(n, axis=1, keepdims=True), atol=1e-6)
    # Tangents orthogonal to the normals, unit, in the plane of (tangent, normal).
    t = np.asarray(maps.tangent, np.float64)
    assert np.max(np.abs(np.sum(t * got_n, 1))) < 1e-6
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(t, np.asarray(surf.tangent), atol=1e-5)
    assert maps.model.dtype == jnp.int32 and int(maps.model[0]) == len(MODELS) - 1
    # Unit normals and tangents are kept bit for bit.
    same = relight.material_maps(surf, 0.5, 0.04, 0.3)
    np.testing.assert_array_equal(np.asarray(same.normal), np.asarray(surf.normal))
    np.testing.assert_array_equal(np.asarray(same.tangent), np.asarray(surf.tangent))


def test_traced_maps_are_not_inspected(surf):
    """Under jit and grad the values are unknown at construction: building
    MaterialMaps from tracers must work (the checks apply to concrete maps)."""
    P = surf.num_samples
    base = relight.material_maps(surf, 0.5, 0.04, 0.3)

    def total(rho_s):
        m = relight.MaterialMaps(base.rho_d, rho_s, base.alpha, base.normal, base.tangent, base.mfp, base.model)
        return jnp.sum(m.rho_s * 2.0)

    rho_s = jnp.full((P, 1), 0.04, jnp.float32)
    assert float(jax.jit(total)(rho_s)) == pytest.approx(0.08 * P, rel=1e-5)
    np.testing.assert_allclose(np.asarray(jax.grad(total)(rho_s)), 2.0)


@pytest.mark.parametrize("field, value, match", [("specular", 5.0, r"rho_s .* must be in \[0, 1\]"),
                                                 ("alpha", 1e30, r"alpha .* must be in \(0, 1\]"),
                                                 ("normal", 0.0, r"normal must be nonzero"),
                                                 ("albedo", 3.0, r"rho_d .* must be in \[0, 1\]")])
def test_a_loaded_texture_set_is_checked(surf, field, value, match):
    """A texture set (what relight.io.read_maps returns) with bad texels is
    refused when its maps are taken at the surface's samples."""
    tex = texture_set(relight.material_maps(surf, 0.5, 0.04, 0.3), surf)
    arr = np.array(getattr(tex, field))
    H, W = tex.resolution
    flat = arr.reshape(H * W, -1)
    flat[np.asarray(surf.texel_index)[:5]] = value
    bad = dataclasses.replace(tex, **{field: flat.reshape(arr.shape)})
    with pytest.raises(ValueError, match=match) as err:
        bad.maps(surf)
    assert f"5 of {surf.num_samples} sample(s)" in str(err.value)
