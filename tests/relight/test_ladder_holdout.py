"""The ladder's held-out observations (relight.fitting._ladder.heldout_weights, specular_cosines): each
sample's valid observations ranked from its mirror direction outward, every ``holdout``-th held out, so a
highlight on a few lights always loses one to the held-out set and keeps the rest for training. Closed-form
cases; what it does on real and rendered data is scripts/eval_outside.py's and eval_mitsuba_photos.py's."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from relight.fitting._ladder import heldout_weights, specular_cosines


def _dt():
    return np.dtype(jnp.result_type(float))  # the fit's dtype (float64 under x64)


def test_every_holdout_th_observation_from_the_mirror_direction_is_held_out():
    """One sample, 15 observations in a shuffled order, 3 of them invalid. Ranked by cos_h (highest first)
    among the 12 valid ones, holdout 5 holds out ranks 2 and 7: the third and eighth closest to the mirror
    direction, never the closest (the peak stays in training), never an invalid one, with w's weights."""
    rng = np.random.default_rng(0)
    cos_h = rng.permutation(np.linspace(0.99, 0.2, 15))
    valid = np.ones(15, bool)
    valid[[1, 6, 11]] = False
    w = (valid[:, None] * np.array([1.0, 0.5, 2.0]))[None].astype(_dt())
    held = heldout_weights(w, cos_h[None], 5)[0]
    ranked = np.nonzero(valid)[0][np.argsort(-cos_h[valid], kind="stable")]
    expected = np.zeros(15, bool)
    expected[ranked[[2, 7]]] = True
    np.testing.assert_array_equal(held[:, 0] > 0, expected)
    np.testing.assert_array_equal(held[expected], w[0][expected])
    assert not np.any(held[~valid]) and held[ranked[0], 0] == 0
    # Of any holdout consecutive valid ranks, exactly one is held out (the strata), whatever holdout is.
    for holdout in (2, 3, 5, 7):
        h = heldout_weights(w, cos_h[None], holdout)[0, :, 0] > 0
        per_stratum = np.add.reduceat(h[ranked], np.arange(0, 12, holdout))
        assert np.all(per_stratum[: 12 // holdout] == 1)


def test_specular_cosines_use_the_surface_normal_or_photometric_stereo():
    """Without normal fitting: the half vector's z (the surface frame's normal). With it: the half vector
    against the photometric-stereo normal of the sample's own data; here noise-free Lambertian radiance for
    a normal tilted 20 degrees, which photometric stereo recovers, so the cosines are those of the tilted
    normal to 1e-3."""
    rng = np.random.default_rng(1)
    n_true = np.array([np.sin(np.radians(20.0)), 0.0, np.cos(np.radians(20.0))])
    wi = rng.normal(size=(40, 3))
    wi[:, 2] = np.abs(wi[:, 2]) + 0.5
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo = np.tile([0.0, 0.0, 1.0], (40, 1))
    irr = np.ones((40, 3))
    obs = 0.4 / np.pi * np.maximum(wi @ n_true, 0.0)[:, None] * irr
    w = np.ones((40, 3)) * (wi @ n_true > 0.05)[:, None]
    data = tuple(x[None].astype(_dt()) for x in (obs, w, wi, wo, irr))
    h = (wi + wo) / np.linalg.norm(wi + wo, axis=1, keepdims=True)
    np.testing.assert_allclose(specular_cosines(data, False, 4)[0], h[:, 2], atol=1e-6)
    np.testing.assert_allclose(specular_cosines(data, True, 4)[0], h @ n_true, atol=1e-3)
