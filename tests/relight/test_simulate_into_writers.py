"""relight.io's capture writers under stage.simulate_into: CaptureFolderWriter and CaptureStoreWriter are
stage.CaptureWriter s and hold what the stream wrote, on the full texel grid."""

import numpy as np
import pytest

import brdf
import stage
from relight.io import CaptureFolderWriter, CaptureStoreWriter, open_capture_store, read_capture, store_blocks

from ..scenes import uv_sphere

RES = 8


def test_folder_and_store_writers_hold_the_stream(tmp_path):
    mesh = uv_sphere(radius=50.0, n_lat=12, n_lon=24)
    full = stage.texel_samples(mesh, RES)
    rig = stage.geodesic_dome(0)
    cam = stage.look_at((0.0, 0.0, 1000.0), fov_deg=8, width=24, height=24)
    vis = stage.camera_visibility(mesh, full, [cam])
    seen = np.flatnonzero(vis[0])
    surface = full.subset(seen)
    P, L = surface.num_samples, rig.num_lights
    material = brdf.lambert_ggx(np.full((P, 3), 0.5, np.float32), np.full((P, 1), 0.04, np.float32),
                                np.full((P, 1), 0.3, np.float32))
    sensor = stage.Sensor(exposure=500.0, shot_noise=True)
    shape = (1, L, RES * RES, 3)
    block, chunk = store_blocks(RES * RES, 32, 3, np.float32)
    folder = CaptureFolderWriter(tmp_path / "f", shape, np.float32, rig, [cam], {"note": "x"},
                                 sample_shape=(RES, RES))
    store = CaptureStoreWriter(tmp_path / "s.zarr", shape, np.float32, rig, [cam], {"note": "x"}, (1, 8, chunk, 3),
                               sample_shape=(RES, RES))
    assert isinstance(folder, stage.CaptureWriter) and isinstance(store, stage.CaptureWriter)
    # One stream for both writers (two blocks of 32 texels, the store's chunk): one compile of the block
    # kernel, and the two writers must then hold the same values bit for bit. (Another block size, which
    # XLA may round differently, is test_cli_simulate_store's: the store against the folder form.)
    assert block < RES * RES
    for writer in (folder, store):
        with writer:
            stage.simulate_into(writer, mesh, surface, rig, [cam], material, vis[:, seen], sensor=sensor, seed=1,
                                block=block, light_chunk=8)
    f = read_capture(tmp_path / "f")
    rad_s, mask_s = open_capture_store(tmp_path / "s.zarr").read()
    np.testing.assert_array_equal(f.radiance, folder.radiance)
    np.testing.assert_array_equal(np.broadcast_to(f.valid, mask_s.shape), mask_s)
    np.testing.assert_array_equal(rad_s, f.radiance)
    assert mask_s.sum() > 0 and not mask_s[:, :, np.setdiff1d(np.arange(RES * RES), seen)].any()


def test_simulate_texel_capture_names_its_arguments_in_errors(tmp_path):
    """relight.simulation.simulate_texel_capture's ValueErrors start with the argument they are about (the CLI turns
    them into errors naming its flags); nothing is left at ``out``."""
    from relight.simulation import MeanFreePath, simulate_texel_capture

    mesh = uv_sphere(radius=50.0, n_lat=12, n_lon=24)
    rig = stage.geodesic_dome(0)
    away = stage.look_at((0.0, 0.0, 1000.0), target=(0.0, 0.0, 2000.0), fov_deg=8, width=24, height=24)
    front = stage.look_at((0.0, 0.0, 1000.0), fov_deg=8, width=24, height=24)
    with pytest.raises(ValueError, match="^cameras: no texel"):
        simulate_texel_capture(tmp_path / "a", mesh, RES, rig, [away], surface_info={})
    with pytest.raises(ValueError, match="^mean_free_path: the mean free path is 0"):
        simulate_texel_capture(tmp_path / "b", mesh, RES, rig, [front], surface_info={},
                               subsurface=MeanFreePath(np.zeros((4, 4, 3))))
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
