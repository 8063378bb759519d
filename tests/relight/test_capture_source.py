"""relight.io.CaptureSource: one read interface for a stage.Capture (ArraySource), a capture folder
(CaptureReader), a capture store (CaptureStore) and a SampleSubset of either; the same arrays from each."""

import jax.numpy as jnp
import numpy as np
import pytest

import stage
from relight.io import (
    ArraySource,
    CaptureSource,
    SampleSubset,
    capture_source,
    open_capture,
    open_capture_store,
    valid_counts,
    write_capture,
    write_capture_store,
)


@pytest.fixture(scope="module")
def capture():
    rng = np.random.default_rng(5)
    rig = stage.geodesic_dome(0)  # 12 lights
    V, L, P = 2, rig.num_lights, 40
    cams = [stage.look_at((0.0, 0.0, 100.0 + v), fov_deg=10, width=8, height=5) for v in range(V)]
    radiance = jnp.asarray(rng.uniform(0, 5, (V, L, P, 3)), jnp.float32)
    mask = jnp.asarray(rng.random((V, L, P)) > 0.3)
    return stage.Capture(radiance=radiance, mask=mask, rig=rig, cameras=tuple(cams))


@pytest.fixture(scope="module")
def sources(capture, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("sources")
    write_capture(tmp / "cap", np.asarray(capture.radiance), capture.rig, list(capture.cameras),
                  valid=np.asarray(capture.mask), sample_shape=(5, 8))
    write_capture_store(tmp / "cap.zarr", capture, chunks=(1, 2, 16, 3))
    return {"array": capture_source(capture), "folder": open_capture(tmp / "cap"),
            "store": open_capture_store(tmp / "cap.zarr")}


@pytest.mark.parametrize("kind", ["array", "folder", "store"])
def test_every_source_reads_the_same(capture, sources, kind):
    src = sources[kind]
    assert isinstance(src, CaptureSource)
    assert tuple(src.shape) == tuple(capture.radiance.shape)
    rad, mask = np.asarray(capture.radiance), np.asarray(capture.mask)
    r, m = src.read(samples=slice(7, 29))
    np.testing.assert_array_equal(r, rad[:, :, 7:29])
    np.testing.assert_array_equal(m, mask[:, :, 7:29])
    assert m.dtype == bool
    np.testing.assert_array_equal(src.read_mask(samples=slice(3, 11)), mask[:, :, 3:11])
    r, m = src.read(views=[1], lights=[4, 0])
    np.testing.assert_array_equal(r, rad[1][[4, 0]][None])
    np.testing.assert_array_equal(m, mask[1][[4, 0]][None])
    np.testing.assert_array_equal(valid_counts(src, 16), mask.sum(axis=(0, 1)))
    assert len(src.stage_cameras()) == 2
    np.testing.assert_allclose(np.asarray(src.stage_rig().directions), np.asarray(capture.rig.directions),
                               rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("kind", ["folder", "store"])
def test_a_sample_subset_is_a_source(capture, sources, kind):
    idx = np.array([1, 2, 5, 17, 30, 39])
    sub = SampleSubset(sources[kind], idx)
    assert isinstance(sub, CaptureSource) and sub.shape[2] == len(idx)
    rad, mask = np.asarray(capture.radiance)[:, :, idx], np.asarray(capture.mask)[:, :, idx]
    r, m = sub.read(samples=slice(1, 5))
    np.testing.assert_array_equal(r, rad[:, :, 1:5])
    np.testing.assert_array_equal(m, mask[:, :, 1:5])
    np.testing.assert_array_equal(sub.read_mask(samples=slice(0, 6)), mask)
    np.testing.assert_array_equal(valid_counts(sub, 4), mask.sum(axis=(0, 1)))


def test_a_folder_without_valid_channel_is_all_valid(capture, tmp_path):
    write_capture(tmp_path / "cap", np.asarray(capture.radiance), capture.rig, list(capture.cameras))
    reader = open_capture(tmp_path / "cap")
    assert reader.read_mask(samples=slice(0, 9)).all() and reader.read_mask().shape == capture.mask.shape
    assert reader.read(lights=2)[1].all()


def test_capture_source_adapts_or_refuses(capture, sources):
    assert isinstance(capture_source(capture), ArraySource)
    assert capture_source(sources["store"]) is sources["store"]
    with pytest.raises(TypeError, match="capture must be a stage.Capture"):
        capture_source(np.zeros((1, 2, 3, 3)))
