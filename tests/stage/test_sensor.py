import jax
import jax.numpy as jnp
import numpy as np
import pytest

import stage

N = 40_000  # draws per channel: the sample mean's error is sqrt(var / N), the variance's ~sqrt(2 / N) = 0.7%


def test_noise_mean_and_variance_match_the_model(key):
    sensor = stage.Sensor(exposure=1000.0, gain=2.0, white_balance=jnp.array([1.0, 0.8, 1.5]), black_level=64.0,
                          read_noise=5.0, shot_noise=True, bits=12)
    L = jnp.full((N, 3), 0.5)
    dn, sat = sensor.expose(key, L)
    assert not bool(sat.any())
    dn = np.asarray(dn, np.float64)
    np.testing.assert_array_equal(dn, np.round(dn))  # quantised to integers
    mean, var = np.asarray(sensor.mean(L[:1]))[0], np.asarray(sensor.variance(L[:1]))[0]
    # Closed form: wb * 1000 * 0.5 / 2 + 64 and (wb / 2)^2 (500 + 25) + 1/12.
    np.testing.assert_allclose(mean, np.array([1.0, 0.8, 1.5]) * 250 + 64, rtol=1e-6)
    np.testing.assert_allclose(var, (np.array([1.0, 0.8, 1.5]) / 2) ** 2 * 525 + 1 / 12, rtol=1e-6)
    # Five standard errors on the mean; 5% on the variance (7 standard errors).
    assert np.all(np.abs(dn.mean(0) - mean) < 5 * np.sqrt(var / N))
    np.testing.assert_allclose(dn.var(0), var, rtol=5e-2)
    # Linearised back to radiance: unbiased.
    np.testing.assert_allclose(np.asarray(sensor.to_radiance(dn)).mean(0), 0.5, rtol=2e-3)


def test_shot_noise_alone_is_poisson(key):
    sensor = stage.Sensor(exposure=20.0, shot_noise=True)
    dn, _ = sensor.expose(key, jnp.full((N, 3), 1.0))
    dn = np.asarray(dn, np.float64)
    np.testing.assert_array_equal(dn, np.round(dn))  # whole electrons at gain 1
    np.testing.assert_allclose([dn.mean(), dn.var()], [20.0, 20.0], rtol=5e-2)


def test_noise_is_seeded(key):
    sensor = stage.Sensor(exposure=100.0, read_noise=2.0, shot_noise=True)
    L = jnp.linspace(0.0, 1.0, 3 * N).reshape(N, 3)  # the shape of the other tests: one compilation
    a, _ = sensor.expose(key, L)
    b, _ = sensor.expose(key, L)
    c, _ = sensor.expose(jax.random.PRNGKey(1), L)
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert np.any(np.asarray(a) != np.asarray(c))


def _capture(radiance):
    rig = stage.geodesic_dome(0)
    rad = jnp.asarray(radiance, jnp.float32)[None, None, :, :]
    rad = jnp.broadcast_to(rad, (1, rig.num_lights) + np.shape(radiance))
    return stage.Capture(radiance=rad, mask=jnp.ones(rad.shape[:3], bool), rig=rig,
                         cameras=(stage.look_at((0.0, 0.0, 1000.0)),))


def test_saturation_clears_the_mask(key):
    cap = _capture([[0.1, 0.1, 0.1], [5.0, 0.1, 0.1], [0.1, 0.1, 0.3]])
    # Without noise or limits the sensor is the identity on radiance.
    clean = stage.sense(cap, stage.Sensor(exposure=1000.0), key)
    np.testing.assert_allclose(np.asarray(clean.radiance), np.asarray(cap.radiance), rtol=1e-6)
    assert bool(clean.mask.all())
    well = stage.sense(cap, stage.Sensor(exposure=1000.0, full_well=2000.0), key)
    np.testing.assert_array_equal(np.asarray(well.mask[0, 0]), [True, False, True])
    np.testing.assert_allclose(np.asarray(well.radiance[0, 0, 1, 0]), 2.0, rtol=1e-6)  # clipped at the full well
    # 8 bits at gain 1: white level 255 DN = 0.255 radiance.
    adc = stage.sense(cap, stage.Sensor(exposure=1000.0, bits=8), key)
    np.testing.assert_array_equal(np.asarray(adc.mask[0, 0]), [True, False, False])
    assert adc.sensor is not None and float(well.sensor.full_well) == 2000.0


@pytest.mark.parametrize("kw, msg", [(dict(exposure=0.0), "exposure"), (dict(bits=40), "bits"),
                                     (dict(read_noise=-1.0), "read_noise"), (dict(full_well=-5.0), "full_well")])
def test_bad_sensor_parameters(kw, msg):
    with pytest.raises(ValueError, match=msg):
        stage.Sensor(**kw)
