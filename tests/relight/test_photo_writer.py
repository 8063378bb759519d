"""Photo captures written as they are simulated: ``stage.iter_images`` (a light chunk of one camera at a time),
``relight.io.PhotoCaptureWriter`` and ``relight simulate --space image --format png`` (a sensor's 16-bit counts)."""

import json

import numpy as np
import pytest

import brdf
import stage
from relight.cli import main
from relight.io import PhotoCaptureWriter, read_photo_capture, write_photo_capture

SIZE = 16


@pytest.fixture(scope="module")
def scene():
    mesh = stage.load_head()
    return mesh, stage.geodesic_dome(1), [stage.front_camera(mesh, SIZE)]


def test_chunks_are_the_whole_stacks_with_the_same_noise(scene):
    """iter_images in chunks of 5 lights gives simulate_images' photographs exactly: the noise of a photograph is
    keyed by (view, light, pixel), not by the chunk it was drawn in."""
    mesh, rig, cams = scene
    material = brdf.lambert_ggx(np.array([[0.5, 0.4, 0.3]], np.float32), np.array([[0.04]], np.float32),
                                np.array([[0.3]], np.float32))
    sensor = stage.Sensor(exposure=500.0, read_noise=2.0, shot_noise=True)
    images, masks = stage.simulate_images(mesh, rig, cams, material, sensor=sensor, seed=3)
    starts = []
    for view, lights, img, mask in stage.iter_images(mesh, rig, cams, material, sensor=sensor, seed=3,
                                                     light_chunk=5):
        starts.append(lights.start)
        assert img.shape == (lights.stop - lights.start, SIZE, SIZE, 3) and img.dtype == np.float32
        np.testing.assert_array_equal(img, images[view][lights])
        np.testing.assert_array_equal(mask, masks[view])
    assert starts == list(range(0, rig.num_lights, 5))
    assert images[0][:, masks[0]].max() > 0 and np.all(images[0][:, ~masks[0]] == 0)
    with pytest.raises(ValueError, match="light_chunk must be >= 1"):
        next(stage.iter_images(mesh, rig, cams, material, light_chunk=0))


def test_a_photograph_never_written_leaves_nothing(scene, tmp_path):
    """The writer swaps the folder into place only when every (camera, light) photograph is there; otherwise the
    folder (here an earlier capture) is as it was."""
    mesh, rig, cams = scene
    stack = np.full((rig.num_lights, SIZE, SIZE, 3), 0.25, np.float32)
    out = write_photo_capture(tmp_path / "photos", [stack], rig, cams)
    before = sorted(p.name for p in (out / "cam000").iterdir())
    with pytest.raises(ValueError, match=r"1 photograph\(s\) never written, the first camera 0 \(cam000\) under "
                                         r"light 41"):
        with PhotoCaptureWriter(out, rig, cams) as w:
            w.write(0, slice(0, rig.num_lights - 1), 0.5 * stack[:-1])
    assert sorted(p.name for p in (out / "cam000").iterdir()) == before
    assert read_photo_capture(out).read_view(0, lights=[0]).radiance.max() == pytest.approx(0.25)
    assert [p.name for p in tmp_path.iterdir()] == ["photos"]  # no hidden folder left behind
    with pytest.raises(ValueError, match=r"must be \[2, 16, 16, C\]"):
        with PhotoCaptureWriter(tmp_path / "other", rig, cams) as w:
            w.write(0, slice(0, 2), stack[:3])
    assert [p.name for p in tmp_path.iterdir()] == ["photos"]


def test_png_photographs_are_the_sensors_counts(tmp_path, capsys):
    """`--format png` writes the sensor's counts (counts = exposure x radiance, 16 bits): read back, the radiance
    is the EXR capture's (same sensor, same seed) within half a count; a count at full scale is invalid under its
    light, and the settings say what fraction was clipped."""
    base = ["simulate", "--space", "image", "--rig", "dome:42", "--image-size", str(SIZE), "--no-index", "--quiet"]
    exposure = 200.0
    sensor = ["--noise", str(exposure), "--read-noise", "2"]
    assert main([*base, *sensor, "--out", str(tmp_path / "exr")]) == 0
    assert main([*base, *sensor, "--format", "png", "--out", str(tmp_path / "png")]) == 0
    exr, png = (read_photo_capture(tmp_path / n).read_view(0) for n in ("exr", "png"))
    assert sorted(p.suffix for p in (tmp_path / "png" / "cam000").iterdir()) == [".png"] * 43  # 42 + the mask
    np.testing.assert_array_equal(png.mask, exr.mask)
    inside = exr.mask
    assert exr.radiance[:, inside].max() * exposure < 65535  # nothing clipped at this exposure
    np.testing.assert_allclose(png.radiance[:, inside], exr.radiance[:, inside], rtol=0, atol=0.5 / exposure + 1e-6)
    assert png.valid[:, inside].all()

    hot = 1e7
    assert main([*base, "--noise", str(hot), "--format", "png", "--out", str(tmp_path / "hot")]) == 0
    view = read_photo_capture(tmp_path / "hot").read_view(0)
    clipped = json.loads((tmp_path / "hot" / "settings.json").read_text())["resolved"]["clipped_fraction"]
    valid = view.valid[:, inside]
    assert 0 < clipped < 1 and 0 < valid.mean() < 1
    assert view.radiance[:, inside][valid].max() * hot < 65535  # what is kept is below full scale
    far_above = exr.radiance[:, inside].max(axis=-1) * hot >= 20 * 65535  # clipped whatever the noise
    assert far_above.any() and not valid[far_above].any()  # a clipped pixel is invalid under its light

    for flags, said in ((["--format", "png"], "give the sensor with --noise"),
                        (["--noise", "100", "--format", "png", "--half"], "--half: applies to EXR"),
                        (["--noise", "100", "--format", "png", "--space", "texel"], "photographs only")):
        assert main([*base, *flags, "--out", str(tmp_path / "refused")]) == 1
        assert said in capsys.readouterr().err
