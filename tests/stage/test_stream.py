"""stage.simulate_into (the streaming simulator), stage.sense_keyed / observation_key (the one sensor-noise
seeding rule), stage.subsurface_from_maps and camera_visibility's chunks, on a small sphere."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import brdf
import skin_bssrdf
import stage

from ..scenes import uv_sphere

RES = 16
# simulate_into and stage.simulate run the same kernels on differently shaped chunks (padded blocks of 16
# lights against every sample and 64 lights), so XLA may round the last bit differently: 2 float32 ulps on one
# machine, up to 1.4e-6 relative (12 ulps) on another of the same kind whose CPU vectorises the sums differently.
RTOL, ATOL = 2e-6, 1e-7
SENSOR = stage.Sensor(exposure=300.0, read_noise=2.0, shot_noise=True)


class Recorder:
    """A stage.CaptureWriter holding the capture, counting how often each element is written."""

    def __init__(self, shape):
        self.radiance = np.zeros(shape, np.float32)
        self.mask = np.zeros(shape[:3], bool)
        self.count = np.zeros(shape[:3], np.int32)

    def write(self, view, lights, samples, radiance, mask):
        assert isinstance(view, int) and isinstance(lights, slice) and isinstance(samples, slice)
        assert radiance.dtype == np.float32 and mask.dtype == bool
        assert isinstance(radiance, np.ndarray) and isinstance(mask, np.ndarray)
        self.radiance[view, lights, samples] = radiance
        self.mask[view, lights, samples] = mask
        self.count[view, lights, samples] += 1


@pytest.fixture(scope="module")
def scene():
    mesh = uv_sphere(radius=50.0, n_lat=24, n_lon=48)
    full = stage.texel_samples(mesh, RES)
    rig = stage.geodesic_dome(1)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=8, width=48, height=48)
    cv_full = stage.camera_visibility(mesh, full, [cam])
    seen = np.nonzero(cv_full[0])[0]
    surface = full.subset(seen)
    uv = np.asarray(surface.uv, np.float32)
    P = surface.num_samples
    rho = np.stack([0.5 + 0.2 * uv[:, 0], 0.4 + 0.1 * uv[:, 1], np.full(P, 0.3, np.float32)], 1)
    material = brdf.lambert_ggx(jnp.asarray(rho), jnp.full((P, 1), 0.04, jnp.float32),
                                jnp.asarray(0.2 + 0.2 * uv[:, :1]))
    lv = stage.light_visibility(mesh, surface, rig)
    cv = cv_full[:, seen]
    ref = stage.simulate(surface, rig, [cam], material, lv, cv)
    return dict(mesh=mesh, full=full, rig=rig, cam=cam, surface=surface, material=material, cv=cv, ref=ref,
                tex=np.asarray(surface.texel_index))


def _stream(scene, **kw):
    rec = Recorder((1, scene["rig"].num_lights, RES * RES, 3))
    out = stage.simulate_into(rec, scene["mesh"], scene["surface"], scene["rig"], [scene["cam"]], scene["material"],
                              scene["cv"], **kw)
    return rec, out


@pytest.fixture(scope="module")
def streams(scene):
    return {"b64": _stream(scene, block=64, light_chunk=16), "one": _stream(scene, block=RES * RES, light_chunk=42),
            "b64_noisy": _stream(scene, block=64, light_chunk=16, sensor=SENSOR, seed=5),
            "one_noisy": _stream(scene, block=1 << 14, light_chunk=42, sensor=SENSOR, seed=5)}


def test_stream_equals_simulate(scene, streams):
    """Noise-free, blocks of 64 texels: stage.simulate's capture on the seen texels (within float32 rounding),
    the unseen texels 0 and invalid, every element written once, the summary's preview the light sum."""
    rec, out = streams["b64"]
    tex, ref = scene["tex"], scene["ref"]
    assert np.all(rec.count == 1)
    assert out.blocks == 4 and out.block == 64
    np.testing.assert_array_equal(rec.mask[:, :, tex], np.asarray(ref.mask))
    np.testing.assert_allclose(rec.radiance[:, :, tex], np.maximum(np.asarray(ref.radiance), 0), rtol=RTOL, atol=ATOL)
    off = np.setdiff1d(np.arange(RES * RES), tex)
    assert not rec.mask[:, :, off].any() and not rec.radiance[:, :, off].any()
    np.testing.assert_allclose(out.all_lights, rec.radiance[0].sum(axis=0), rtol=1e-5, atol=1e-6)
    assert rec.mask.sum() > 500


def test_noise_does_not_depend_on_blocks_or_chunks(streams):
    """One seed: blocks of 64 texels with 16-light chunks and one block with 42-light chunks give the same noisy
    capture (every observation has its own key)."""
    (a, _), (b, _) = streams["b64_noisy"], streams["one_noisy"]
    np.testing.assert_array_equal(a.mask, b.mask)
    np.testing.assert_allclose(a.radiance, b.radiance, rtol=1e-6, atol=0)
    clean, _ = streams["b64"]
    assert not np.array_equal(a.radiance, clean.radiance)


def test_stream_noise_is_sense_keyed_of_simulate(scene, streams):
    """The streamed noise is stage.sense_keyed's of stage.simulate's capture: the one seeding rule."""
    rec, _ = streams["one_noisy"]
    ref, tex = scene["ref"], scene["tex"]
    r, m = stage.sense_keyed(SENSOR, 5, ref.radiance[0], ref.mask[0], view=0, lights=0, samples=tex)
    np.testing.assert_array_equal(rec.mask[0][:, tex], m)
    np.testing.assert_allclose(rec.radiance[0][:, tex], r, rtol=1e-6, atol=0)


def test_sense_keyed_is_per_observation(key):
    """Cutting a chunk into smaller ones (lights or samples) changes no value, and one observation's value is
    Sensor.expose with observation_key(seed, view, light, sample)."""
    rad = jax.random.uniform(key, (6, 40, 3), jnp.float32, 0.0, 2.0)
    mask = np.ones((6, 40), bool)
    samples = np.arange(100, 140)
    whole, _ = stage.sense_keyed(SENSOR, 3, rad, mask, view=2, lights=10, samples=samples)
    part, _ = stage.sense_keyed(SENSOR, 3, rad[2:5, 7:30], mask[2:5, 7:30], view=2, lights=np.arange(12, 15),
                                samples=samples[7:30])
    np.testing.assert_array_equal(part, whole[2:5, 7:30])
    dn, _ = SENSOR.expose(stage.observation_key(3, 2, 13, 120), rad[3, 20])
    np.testing.assert_allclose(whole[3, 20], np.asarray(SENSOR.to_radiance(dn)), rtol=1e-6)
    other, _ = stage.sense_keyed(SENSOR, 4, rad, mask, view=2, lights=10, samples=samples)
    assert not np.array_equal(other, whole)
    clean, _ = stage.sense_keyed(None, 3, rad, mask, view=2, lights=10, samples=samples)
    np.testing.assert_array_equal(clean, np.asarray(rad))


def test_sense_keyed_refuses_mismatched_shapes():
    with pytest.raises(ValueError, match="samples"):
        stage.sense_keyed(SENSOR, 0, np.ones((2, 5, 3)), np.ones((2, 5), bool), view=0, lights=0,
                          samples=np.arange(4))
    with pytest.raises(ValueError, match="mask"):
        stage.sense_keyed(SENSOR, 0, np.ones((2, 5, 3)), np.ones((2, 4), bool), view=0, lights=0,
                          samples=np.arange(5))


def test_stream_refuses_bad_input(scene):
    rec = Recorder((1, scene["rig"].num_lights, RES * RES, 3))
    args = (rec, scene["mesh"], scene["surface"], scene["rig"], [scene["cam"]], scene["material"])
    with pytest.raises(ValueError, match="camera_visibility"):
        stage.simulate_into(*args, scene["cv"][:, :-1])
    with pytest.raises(ValueError, match="block"):
        stage.simulate_into(*args, scene["cv"], block=0)
    backwards = scene["surface"].subset(np.arange(scene["surface"].num_samples)[::-1])
    with pytest.raises(ValueError, match="texel_index"):
        stage.simulate_into(rec, scene["mesh"], backwards, scene["rig"], [scene["cam"]], scene["material"],
                            scene["cv"])


def test_camera_visibility_in_chunks_is_the_same(scene):
    whole = stage.camera_visibility(scene["mesh"], scene["full"], [scene["cam"]])
    chunked = stage.camera_visibility(scene["mesh"], scene["full"], [scene["cam"]], chunk=37)
    np.testing.assert_array_equal(chunked, whole)


def test_subsurface_from_maps(scene):
    """Samples with a mean free path scatter (Burley dmfp of their albedo), the others have albedo 0; the radius
    is skin_bssrdf.operator_radius over the scattering ones; eta defaults to skin's."""
    surface = scene["surface"]
    P = surface.num_samples
    on = np.arange(P) % 2 == 0
    mfp = np.where(on[:, None], np.array([[1.0, 0.5, 0.25]]), 0.0)
    rho = np.full((P, 3), 0.5)
    sss = stage.subsurface_from_maps(surface, rho, mfp)
    assert sss.eta == skin_bssrdf.SKIN_ETA and sss.operator.num_samples == P
    assert sss.operator.radius == pytest.approx(skin_bssrdf.operator_radius(sss.profile, where=on))
    total = np.asarray(sss.profile.albedo)
    assert np.all(total[~on] == 0) and np.all(total[on] > 0)
    with pytest.raises(ValueError, match="every sample"):
        stage.subsurface_from_maps(surface, rho, np.zeros((P, 3)))
    with pytest.raises(ValueError, match="mean_free_path"):
        stage.subsurface_from_maps(surface, rho, -mfp)
