"""Camera-space photo captures (relight.io.read_photo_capture, docs/capture_layout.md)
and rig files as real stages ship them (stage.load_rig_file)."""

import json

import numpy as np
import pytest

import stage
from relight.image import srgb_decode
from relight.io import (
    ImageFormatError,
    PhotoCapture,
    read_photo_capture,
    write_exr,
    write_photo_capture,
    write_png,
)

L, H, W = 20, 12, 16


@pytest.fixture
def rig():
    return stage.fibonacci_sphere(L)


@pytest.fixture
def cams():
    return stage.camera_ring(2, 1000.0, width=W, height=H)


def _images(seed=0, hi=1.0):
    rng = np.random.default_rng(seed)
    return [rng.uniform(0.0, hi, (L, H, W, 3)).astype(np.float32) for _ in range(2)]


def _edit(folder, fn):
    p = folder / "capture.json"
    doc = json.loads(p.read_text())
    fn(doc)
    p.write_text(json.dumps(doc))


def test_exr_round_trip_exact_and_lazy(tmp_path, rig, cams):
    imgs = _images(hi=7.0)
    folder = write_photo_capture(tmp_path / "p", imgs, rig, cams, names=["left", "right"])
    cap = read_photo_capture(folder)
    assert isinstance(cap, PhotoCapture) and len(cap) == 2 and cap.names == ["left", "right"]
    assert cap.n_lights == L and cap.distortion == [None, None]
    np.testing.assert_allclose(np.asarray(cap.rig.position), np.asarray(rig.position), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(cap.rig.center_irradiance), np.asarray(rig.center_irradiance), rtol=1e-6)
    for k, view in enumerate(cap):  # one camera at a time
        assert view.radiance.shape == (L, H, W, 3) and view.radiance.dtype == np.float32
        np.testing.assert_array_equal(view.radiance, imgs[k])
        assert view.valid.all() and view.mask.all()
        np.testing.assert_allclose(np.asarray(view.camera.K), np.asarray(cams[k].K))


def test_half_exr_round_trip(tmp_path, rig, cams):
    imgs = _images(hi=3.0)
    cap = read_photo_capture(write_photo_capture(tmp_path / "p", imgs, rig, cams, half=True))
    np.testing.assert_array_equal(cap.read_view(0).radiance, imgs[0].astype(np.float16).astype(np.float32))


def test_png16_linear_and_srgb(tmp_path, rig, cams):
    imgs = _images()
    lin = read_photo_capture(write_photo_capture(tmp_path / "lin", imgs, rig, cams, fmt="png"))
    assert np.abs(lin.read_view(1).radiance - imgs[1]).max() <= 0.5 / 65535 + 1e-7
    srgb = read_photo_capture(write_photo_capture(tmp_path / "srgb", imgs, rig, cams, fmt="png", encoding="srgb"))
    got = srgb.read_view(0).radiance
    # Against relight.image.srgb_decode of the stored 16-bit codes.
    from relight.io import read_png

    codes = np.stack([read_png(p) for p in srgb.files(0)]).astype(np.float64) / 65535
    np.testing.assert_allclose(got, np.asarray(srgb_decode(codes)), atol=1e-6)
    # and the decoded values are the linear originals to the 16-bit quantisation (slope of decode <= 1/12.92*...)
    assert np.abs(got - imgs[0]).max() < 4.0 / 65535
    gam = read_photo_capture(write_photo_capture(tmp_path / "g", imgs, rig, cams, fmt="png", encoding="gamma:2.2"))
    assert np.abs(gam.read_view(0).radiance - imgs[0]).max() < 4.0 / 65535


def test_exposure_gain_saturation_mask(tmp_path, rig, cams):
    imgs = _images(hi=2.0)
    exposure = [np.linspace(0.5, 2.0, L), 4.0]
    gain = [2.0, np.full(L, 0.25)]
    mask = np.zeros((H, W), bool)
    mask[2:10, 3:12] = True
    folder = write_photo_capture(tmp_path / "p", imgs, rig, cams, exposure=exposure, gain=gain,
                                 masks=[mask, None], saturation=1.5)
    cap = read_photo_capture(folder)
    v0, v1 = cap.read_view(0), cap.read_view(1)
    sat0 = np.any(imgs[0] >= 1.5, axis=-1)
    np.testing.assert_array_equal(v0.mask, mask)
    np.testing.assert_array_equal(v0.valid, mask[None] & ~sat0)
    want0 = imgs[0] / (exposure[0] * 2.0)[:, None, None, None]
    np.testing.assert_allclose(v0.radiance, np.where(v0.valid[..., None], want0, 0), rtol=1e-6)
    assert v1.mask.all()
    np.testing.assert_array_equal(v1.valid, ~np.any(imgs[1] >= 1.5, axis=-1))
    np.testing.assert_allclose(v1.radiance, np.where(v1.valid[..., None], imgs[1] / 1.0, 0), rtol=1e-6)


@pytest.mark.parametrize("bad", ["../outside/l{light:03d}.exr", "/tmp/l{light:03d}.exr", "cam000/../../x.exr"])
def test_paths_leaving_the_folder_are_refused(tmp_path, rig, cams, bad):
    folder = write_photo_capture(tmp_path / "p", _images(), rig, cams)
    _edit(folder, lambda d: d["views"][0].__setitem__("images", bad))
    with pytest.raises(ImageFormatError, match=r"capture\.json: views\[0\]: field 'images'.*leaves the capture"):
        read_photo_capture(folder)


def test_rig_and_mask_paths_leaving_the_folder_are_refused(tmp_path, rig, cams):
    folder = write_photo_capture(tmp_path / "p", _images(), rig, cams)
    _edit(folder, lambda d: d.__setitem__("rig", "../rig.json"))
    with pytest.raises(ImageFormatError, match=r"capture\.json: field 'rig'.*leaves"):
        read_photo_capture(folder)
    _edit(folder, lambda d: (d.__setitem__("rig", "rig.json"), d["views"][1].__setitem__("mask", "/etc/passwd")))
    with pytest.raises(ImageFormatError, match=r"views\[1\]: field 'mask'.*leaves"):
        read_photo_capture(folder)


@pytest.mark.parametrize("edit, match", [
    (lambda d: d.__setitem__("format", "other"), r"capture\.json: field 'format'"),
    (lambda d: d.__setitem__("version", 9), r"capture\.json: field 'version'"),
    (lambda d: d["views"][0].__setitem__("camera", "nobody"), r"views\[0\]: field 'camera'"),
    (lambda d: d["views"][1].__setitem__("camera", "cam000"), r"views\[1\]: camera 'cam000' is listed twice"),
    (lambda d: d.__setitem__("rig", {"units": "m"}), r"capture\.json: field 'rig'"),
    (lambda d: d["views"][1].__setitem__("exposure", [1.0, 2.0]), r"views\[1\]: field 'exposure'"),
    (lambda d: d["views"][1].__setitem__("gain", -1), r"views\[1\]: field 'gain'"),
    (lambda d: d.__setitem__("saturation", "high"), r"views\[0\]: field 'saturation'"),
    (lambda d: d.__setitem__("encoding", "log"), r"views\[0\]: field 'encoding'"),
    (lambda d: d["views"][0].__setitem__("images", "cam000/l{light:03d}.tif"), r"views\[0\]: field 'images'"),
    (lambda d: d["views"][0].__setitem__("images", "cam000/m{light:03d}.exr"), r"views\[0\]: .*missing"),
])
def test_bad_capture_json_names_file_and_field(tmp_path, rig, cams, edit, match):
    folder = write_photo_capture(tmp_path / "p", _images(), rig, cams)
    _edit(folder, edit)
    with pytest.raises(ValueError, match=match):
        read_photo_capture(folder)


def test_bad_images_name_the_file(tmp_path, rig, cams):
    folder = write_photo_capture(tmp_path / "p", _images(), rig, cams)
    write_exr(folder / "cam001" / "l003.exr", np.zeros((H, W + 1, 3), np.float32))
    cap = read_photo_capture(folder)
    cap.read_view(0)
    with pytest.raises(ImageFormatError, match=r"cam001/l003\.exr: image is 17x12 but its camera is 16x12"):
        cap.read_view(1)
    bad = np.zeros((H, W, 3), np.float32)
    bad[1, 2, 0] = -1.0
    write_exr(folder / "cam001" / "l003.exr", bad)
    with pytest.raises(ImageFormatError, match=r"cam001/l003\.exr: pixel values has 1 negative"):
        cap.read_view(1)
    write_png(folder / "cam000" / "mask.png", np.zeros((H + 1, W), np.uint8))
    _edit(folder, lambda d: d["views"][0].__setitem__("mask", "cam000/mask.png"))
    # Compared with the camera from the PNG header, before any row is decoded (issue 29: a 261 KB PNG declaring
    # 16384^2 pixels was decoded, 2.9 GB, before its size was looked at).
    with pytest.raises(ImageFormatError, match=r"mask\.png: the PNG header says 16x13 pixels, expected 16x12"):
        read_photo_capture(folder).read_view(0)


def test_bad_camera_and_distortion(tmp_path, rig, cams):
    folder = write_photo_capture(tmp_path / "p", _images(), rig, cams)
    doc = json.loads((folder / "cameras.json").read_text())
    doc["cameras"][1]["distortion"] = [-0.1, 0.02, 0.001, 0.0, 0.003]
    (folder / "cameras.json").write_text(json.dumps(doc))
    cap = read_photo_capture(folder)
    assert cap.distortion[0] is None
    # The camera holds them as float32 (stage.Camera.dist): equal to float32's precision.
    assert cap.distortion[1] == pytest.approx({"k1": -0.1, "k2": 0.02, "p1": 0.001, "p2": 0.0, "k3": 0.003},
                                              rel=1e-7)
    assert np.array_equal(np.asarray(cap.cameras[1].dist), np.float32([-0.1, 0.02, 0.001, 0.0, 0.003]))
    doc["cameras"][1]["distortion"] = [1, 2]
    (folder / "cameras.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"cameras\.json: camera 1: field 'distortion'"):
        read_photo_capture(folder)
    del doc["cameras"][1]["distortion"]
    doc["cameras"][1]["K"] = [[1, 0], [0, 1]]
    (folder / "cameras.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"cameras\.json: camera 1: field 'K'"):
        read_photo_capture(folder)


def test_rig_file_units_subset_calibration(tmp_path, rig, cams):
    folder = write_photo_capture(tmp_path / "p", _images(), rig, cams)
    doc = json.loads((folder / "rig.json").read_text())
    doc["positions"] = (np.asarray(doc["positions"]) / 1000.0).tolist()
    doc["units"] = "m"
    doc["calibration"] = [1.0, 0.5, 2.0]
    doc["subsets"] = {"first10": list(range(10))}
    (folder / "rig.json").write_text(json.dumps(doc))
    cap = read_photo_capture(folder)
    np.testing.assert_allclose(np.asarray(cap.rig.position), np.asarray(rig.position), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(cap.rig.intensity), np.asarray(rig.intensity) * [1.0, 0.5, 2.0], rtol=1e-6)
    sub = read_photo_capture(folder, rig_subset="first10")
    assert sub.n_lights == 10 and sub.read_view(0).radiance.shape[0] == 10
    doc["units"] = "furlongs"
    (folder / "rig.json").write_text(json.dumps(doc))
    with pytest.raises(ValueError, match=r"rig\.json: field 'units'"):
        read_photo_capture(folder)


def test_up_rotation_is_a_rotation():
    for axis, vec in stage.AXES.items():
        R = stage.up_rotation(axis)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(R @ np.asarray(vec, float), [0, 1, 0], atol=1e-12)
    with pytest.raises(ValueError, match="up axis"):
        stage.up_rotation("up")


def test_shared_light_stage_x_table_loads(shared_data):
    path = shared_data / "lightstage" / "light_stage_x.json"
    rig = stage.load_rig_file(path)
    ref = stage.light_stage_x()
    np.testing.assert_allclose(np.asarray(rig.position), np.asarray(ref.position), rtol=1e-6)
    # against the raw table (cm -> mm), the duplicated row 322 aside
    raw = np.asarray(json.loads(path.read_text())["positions_cm"]) * 10.0
    keep = np.arange(len(raw)) != 321
    np.testing.assert_allclose(np.asarray(rig.position)[keep], raw[keep], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(rig.center_irradiance).mean(), 1.0, rtol=0.05)
    pol = stage.load_rig_file(path, subset="polarized")
    np.testing.assert_allclose(np.asarray(pol.position), np.asarray(stage.light_stage_x("polarized").position),
                               rtol=1e-6)
    assert stage.load_rig_file(path, subset="unpolarized").num_lights == 201
    assert set(stage.rig_file_subsets(path)) == {"polarized", "unpolarized"}
    with pytest.raises(ValueError, match="no light subset 'nope'"):
        stage.load_rig_file(path, subset="nope")


def test_shared_openillumination_needs_units_and_up(shared_data):
    path = shared_data / "lightstage" / "openillumination_light_pos.npy"
    with pytest.raises(ValueError, match=r"openillumination_light_pos\.npy: .*no unit.*--rig-units"):
        stage.load_rig_file(path)
    with pytest.raises(ValueError, match=r"openillumination_light_pos\.npy: .*which axis is up.*--rig-up.*up = -y"):
        stage.load_rig_file(path, units="m")
    raw = np.load(path)
    rig = stage.load_rig_file(path, units="m", up="-y")
    assert rig.num_lights == 142 and rig.near_field
    want = raw * [1.0, -1.0, -1.0] * 1000.0  # 180 degrees about +x, metres -> mm
    np.testing.assert_allclose(np.asarray(rig.position), want, rtol=1e-6, atol=1e-3)
    np.testing.assert_allclose(float(np.asarray(rig.solid_angle).sum()), 4 * np.pi, rtol=1e-5)
    dist = stage.load_rig_file(path, units="directions", up="-y")
    assert not dist.near_field
    np.testing.assert_allclose(np.asarray(dist.center_irradiance), 1.0)


def test_text_rig_table(tmp_path):
    d = np.asarray(stage.fibonacci_sphere(12).directions, np.float64)
    p = tmp_path / "lights.txt"
    np.savetxt(p, d * 150.0)
    rig = stage.load_rig_file(p, units="cm", up="+z")
    np.testing.assert_allclose(np.asarray(rig.position), (d @ stage.up_rotation("+z").T) * 1500.0, rtol=1e-5,
                               atol=1e-3)
    np.save(tmp_path / "bad.npy", np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"bad\.npy: light positions must be a numeric \[L, 3\]"):
        stage.load_rig_file(tmp_path / "bad.npy", units="mm", up="+y")
    (tmp_path / "rig.yaml").write_text("x")
    with pytest.raises(ValueError, match=r"rig\.yaml: unknown rig file type"):
        stage.load_rig_file(tmp_path / "rig.yaml")


def test_png_saturation_is_on_stored_values(tmp_path, rig, cams):
    imgs = _images()
    folder = write_photo_capture(tmp_path / "p", imgs, rig, cams, fmt="png", encoding="srgb", saturation=0.9)
    cap = read_photo_capture(folder)
    from relight.io import read_png

    codes = np.stack([read_png(p) for p in cap.files(1)]).astype(np.float64) / 65535
    view = cap.read_view(1)
    np.testing.assert_array_equal(view.valid, ~np.any(codes >= 0.9, axis=-1))
    assert 0 < (~view.valid).sum() < view.valid.size
    assert np.all(view.radiance[~view.valid] == 0)


@pytest.mark.parametrize("make", [lambda: stage.geodesic_dome(1), lambda: stage.light_stage_x("polarized")])
def test_stage_rig_json_reads_as_load_rig(tmp_path, make):
    rig = make()
    path = stage.save_rig(tmp_path / "rig.json", rig)
    a, b = stage.load_rig_file(path), stage.load_rig(path)
    assert a.near_field == b.near_field
    for f in ("position", "intensity", "solid_angle"):
        np.testing.assert_allclose(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)), rtol=1e-6)
